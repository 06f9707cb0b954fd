//! Eq. (16): the command sequence of the paper's dataset.
//!
//! The paper draws 1,802 random configurations inside the joint limits and joins consecutive
//! ones by points spaced 3·√5 apart in joint space (a 3° step on each of the 5 joints), giving
//! 30,707 commands:
//!
//! q_{p_i,j} = q_{p_i} + 3j√5 · (q_{p_{i+1}} − q_{p_i}) / ‖q_{p_{i+1}} − q_{p_i}‖,
//! j = 0 … ⌊‖q_{p_{i+1}} − q_{p_i}‖ / 3√5⌋.
//!
//! Endpoints: for each consecutive pair, j runs from 0 (the pair's start, q_{p_i}) to the
//! floor inclusive, so every random configuration appears exactly once as the j = 0 point of
//! the pair it starts. A last interpolated point that lands on q_{p_{i+1}} (distance an exact
//! multiple of the step) is dropped, because the next pair emits it as its own j = 0, and the
//! final configuration q_{p_{N−1}} is appended once at the end. A pair of identical
//! configurations emits nothing (its start is the next pair's start). The count is therefore
//! Σ_i (⌊d_i / 3√5⌋ + 1) + 1 (minus exact hits).
//!
//! With the shipped joint limits (±60°, ±60°, ±44°, ±50°, ±50°, jaws not crossed) consecutive
//! random configurations are ≈ 87° apart on average, so N configurations give ≈ 13.5·N
//! commands; the paper's ratio is 30,707 / 1,802 ≈ 17.0, i.e. its random configurations were
//! ≈ 110° apart (its joint ranges were evidently wider than the ones published in Table I/II).

use bowden_kinematics::{JointsDeg, Robot, N_JOINTS};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Spacing of consecutive dataset commands in joint space (deg): 3° on each of 5 joints.
pub const DATASET_STEP_DEG: f64 = 6.708_203_932_499_369; // 3·√5

/// Number of random configurations of the paper's dataset.
pub const PAPER_DATASET_CONFIGS: usize = 1_802;
/// Number of commands the paper's dataset has after eq. (16).
pub const PAPER_DATASET_COMMANDS: usize = 30_707;

/// Rejection sampling gives up after this many draws for one configuration (only a robot whose
/// jaw limits leave almost no room for the minimum opening gets there) and falls back to
/// [`Robot::clamp_to_limits`] of the last draw, which opens the jaws symmetrically.
const MAX_DRAWS_PER_CONFIG: usize = 10_000;

/// `n` configurations drawn uniformly inside the joint limits with the jaws not crossed
/// (q5 − q4 ≥ the robot's minimum opening): uniform in the box, rejecting crossed jaws, so the
/// result is uniform over the feasible set. Every returned configuration passes
/// [`Robot::check_limits`].
pub fn random_configurations(robot: &Robot, n: usize, rng: &mut ChaCha8Rng) -> Vec<JointsDeg> {
    let lim = &robot.config.limits;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let mut q = [0.0; N_JOINTS];
        let mut accepted = false;
        for _ in 0..MAX_DRAWS_PER_CONFIG {
            for (j, v) in q.iter_mut().enumerate() {
                *v = rng.random_range(lim.q_min_deg[j]..=lim.q_max_deg[j]);
            }
            if robot.check_limits(&q).is_ok() {
                accepted = true;
                break;
            }
        }
        if !accepted {
            q = robot.clamp_to_limits(&q);
        }
        out.push(q);
    }
    out
}

/// Eq. (16) over a sequence of configurations (see the module docs for the endpoints).
pub fn interpolate_eq16(configs: &[JointsDeg]) -> Vec<JointsDeg> {
    let Some(last) = configs.last() else {
        return Vec::new();
    };
    let mut out = Vec::new();
    for pair in configs.windows(2) {
        out.extend(interpolate_with_step(&pair[0], &pair[1], DATASET_STEP_DEG));
    }
    out.push(*last);
    out
}

/// The dataset commands of eq. (16): `n_configs` random configurations (seeded ChaCha8) joined
/// by 3·√5-spaced interpolation. Same robot + `n_configs` + `seed` give the same commands.
pub fn dataset_commands(robot: &Robot, n_configs: usize, seed: u64) -> Vec<JointsDeg> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let configs = random_configurations(robot, n_configs, &mut rng);
    interpolate_eq16(&configs)
}

/// How the dataset excites the plant beyond eq. (16).
///
/// The paper's sequence moves one 3·√5 step per command, so a model trained on it has never
/// seen the command jump. A hysteresis compensator must jump: on every reversal it crosses the
/// dead band in one command, and its forward model is then asked about a history it never
/// learned (measured here: the shipped forward model's error grows from ≈ 1° on the
/// uncalibrated commands of the test trajectories to 3–5° on the compensated ones). The plant
/// is rate-independent and each command is held until it settles, so a sequence of held commands
/// with larger steps is as physical as eq. (16); a dataset that mixes step sizes and dither
/// covers the commands the compensator actually sends.
#[derive(Debug, Clone, PartialEq)]
pub struct Excitation {
    /// Per segment (pair of random configurations) the step is `DATASET_STEP_DEG ×` one of these,
    /// drawn uniformly. `[1.0]` is eq. (16).
    pub step_multipliers: Vec<f64>,
    /// Per segment, every command but the segment's first is offset by i.i.d. uniform noise of
    /// ± one of these amplitudes (deg, per joint), drawn uniformly; clamped to the *command*
    /// limits, which let the jaws be commanded past each other as the compensator may.
    /// `[0.0]` is eq. (16).
    pub dither_deg: Vec<f64>,
}

/// The named excitations (`bowden collect --excitation`, a transfer recipe's `excitation`).
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    serde::Deserialize,
    serde::Serialize,
    strum::EnumString,
    strum::IntoStaticStr,
    strum::Display,
    strum::VariantNames,
)]
#[serde(rename_all = "lowercase")]
#[strum(serialize_all = "lowercase")]
pub enum ExcitationKind {
    /// eq. (16) exactly ([`Excitation::paper`]).
    Paper,
    /// eq. (16) with jumps and dither ([`Excitation::mixed`]).
    Mixed,
}

impl ExcitationKind {
    pub fn as_str(self) -> &'static str {
        self.into()
    }

    /// The excitation this name stands for.
    pub fn excitation(self) -> Excitation {
        match self {
            Self::Paper => Excitation::paper(),
            Self::Mixed => Excitation::mixed(),
        }
    }
}

impl Excitation {
    /// The paper's eq. (16).
    pub fn paper() -> Self {
        Self {
            step_multipliers: vec![1.0],
            dither_deg: vec![0.0],
        }
    }

    /// eq. (16) mixed with jumps (1–4 steps) and dither (0–20°): what `bowden collect
    /// --excitation mixed` records.
    pub fn mixed() -> Self {
        Self {
            step_multipliers: vec![1.0, 2.0, 3.0, 4.0],
            dither_deg: vec![0.0, 5.0, 10.0, 20.0],
        }
    }

    /// Whether this is plain eq. (16).
    pub fn is_paper(&self) -> bool {
        self.step_multipliers.iter().all(|&m| m == 1.0) && self.dither_deg.iter().all(|&d| d == 0.0)
    }

    fn validate(&self) -> Result<(), ExcitationError> {
        if self.step_multipliers.is_empty() || self.dither_deg.is_empty() {
            return Err(ExcitationError::Empty);
        }
        if let Some(&m) = self.step_multipliers.iter().find(|m| !(m.is_finite() && **m > 0.0)) {
            return Err(ExcitationError::StepMultiplier(m));
        }
        if let Some(&d) = self.dither_deg.iter().find(|d| !(d.is_finite() && **d >= 0.0)) {
            return Err(ExcitationError::Dither(d));
        }
        Ok(())
    }
}

/// An [`Excitation`] that cannot make commands.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum ExcitationError {
    #[error("excitation: step multipliers and dither amplitudes must not be empty")]
    Empty,
    #[error("excitation: step multiplier {0} must be finite and > 0")]
    StepMultiplier(f64),
    #[error("excitation: dither amplitude {0}° must be finite and ≥ 0")]
    Dither(f64),
}

/// Commands for `n_configs` random configurations (seeded ChaCha8) under an [`Excitation`].
/// `Excitation::paper()` gives exactly [`dataset_commands`]. Every command is inside the joint
/// limits.
pub fn excitation_commands(
    robot: &Robot,
    n_configs: usize,
    seed: u64,
    excitation: &Excitation,
) -> Result<Vec<JointsDeg>, ExcitationError> {
    excitation.validate()?;
    if excitation.is_paper() {
        return Ok(dataset_commands(robot, n_configs, seed));
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let configs = random_configurations(robot, n_configs, &mut rng);
    // A second stream for the per-segment choices, so the configurations are those of eq. (16)
    // with the same seed.
    let mut pick = ChaCha8Rng::seed_from_u64(seed ^ 0x9e37_79b9_7f4a_7c15);
    let mut out = Vec::new();
    for pair in configs.windows(2) {
        let m = excitation.step_multipliers[pick.random_range(0..excitation.step_multipliers.len())];
        let amp = excitation.dither_deg[pick.random_range(0..excitation.dither_deg.len())];
        let segment = interpolate_with_step(&pair[0], &pair[1], DATASET_STEP_DEG * m);
        for (j, q) in segment.iter().enumerate() {
            let mut c = *q;
            if j > 0 && amp > 0.0 {
                for v in c.iter_mut() {
                    *v += pick.random_range(-amp..=amp);
                }
                c = robot.clamp_command_to_limits(&c);
            }
            out.push(c);
        }
    }
    if let Some(last) = configs.last() {
        out.push(*last);
    }
    Ok(out)
}

/// One segment of eq. (16) with a given step: from `a` (included) towards `b` (excluded; an exact
/// hit of `b` is the next segment's start). Identical configurations give nothing.
fn interpolate_with_step(a: &JointsDeg, b: &JointsDeg, step_deg: f64) -> Vec<JointsDeg> {
    let delta: [f64; N_JOINTS] = core::array::from_fn(|k| b[k] - a[k]);
    let dist = delta.iter().map(|d| d * d).sum::<f64>().sqrt();
    if dist == 0.0 {
        return Vec::new();
    }
    let n_steps = (dist / step_deg).floor() as usize;
    let mut out = Vec::with_capacity(n_steps + 1);
    for j in 0..=n_steps {
        let s = j as f64 * step_deg;
        // An exact hit of the pair's end is the next pair's j = 0 (or the appended last).
        if j > 0 && (dist - s).abs() < 1e-9 {
            break;
        }
        let t = s / dist;
        out.push(core::array::from_fn(|k| a[k] + t * delta[k]));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dist(a: &JointsDeg, b: &JointsDeg) -> f64 {
        a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<f64>().sqrt()
    }

    #[test]
    fn step_is_three_root_five() {
        assert!((DATASET_STEP_DEG - 3.0 * 5f64.sqrt()).abs() < 1e-15);
    }

    #[test]
    fn spacing_and_counts_follow_eq16() {
        let robot = Robot::paper_default();
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let configs = random_configurations(&robot, 200, &mut rng);
        let cmds = interpolate_eq16(&configs);
        let expected: usize = configs
            .windows(2)
            .map(|w| (dist(&w[0], &w[1]) / DATASET_STEP_DEG).floor() as usize + 1)
            .sum::<usize>()
            + 1;
        assert_eq!(cmds.len(), expected);
        // Walk the sequence: every configuration appears in order, and between two of them
        // consecutive commands are exactly one step apart on the straight line, except the
        // last step into the next configuration, which is shorter (≤ one step).
        let mut k = 0;
        for w in configs.windows(2) {
            assert_eq!(cmds[k], w[0]);
            let n = (dist(&w[0], &w[1]) / DATASET_STEP_DEG).floor() as usize;
            for j in 1..=n {
                let d = dist(&cmds[k + j - 1], &cmds[k + j]);
                assert!((d - DATASET_STEP_DEG).abs() < 1e-9, "step {d}");
            }
            let tail = dist(&cmds[k + n], &w[1]);
            assert!(tail < DATASET_STEP_DEG + 1e-9, "tail {tail}");
            k += n + 1;
        }
        assert_eq!(cmds[k], *configs.last().unwrap());
        assert_eq!(k + 1, cmds.len());
        for q in &cmds {
            robot
                .check_limits(q)
                .expect("interpolated commands stay inside the limits");
        }
    }

    #[test]
    fn ratio_is_close_to_the_papers() {
        let robot = Robot::paper_default();
        let n = 1802;
        let cmds = dataset_commands(&robot, n, 7);
        let ratio = cmds.len() as f64 / n as f64;
        let paper = PAPER_DATASET_COMMANDS as f64 / PAPER_DATASET_CONFIGS as f64;
        // Documented: ≈ 13.5 with the shipped limits against the paper's 17.0.
        assert!(ratio > 12.5 && ratio < paper, "ratio {ratio}");
    }

    #[test]
    fn exact_hits_are_not_duplicated() {
        let a = [0.0; N_JOINTS];
        let b = [3.0 * 2.0; N_JOINTS]; // distance 6√5 = exactly 2 steps
        let cmds = interpolate_eq16(&[a, b, a]);
        // a, a+1 step, b, b+1 step (back), a
        assert_eq!(cmds.len(), 5);
        for w in cmds.windows(2) {
            assert!((dist(&w[0], &w[1]) - DATASET_STEP_DEG).abs() < 1e-9);
        }
        assert!(interpolate_eq16(&[]).is_empty());
        assert_eq!(interpolate_eq16(&[a]), vec![a]);
        assert_eq!(interpolate_eq16(&[a, a, b]).len(), 3);
    }

    #[test]
    fn seeded_and_deterministic() {
        let robot = Robot::paper_default();
        let a = dataset_commands(&robot, 50, 11);
        let b = dataset_commands(&robot, 50, 11);
        let c = dataset_commands(&robot, 50, 12);
        let bytes = |v: &[JointsDeg]| v.iter().flatten().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
        assert_eq!(bytes(&a), bytes(&b));
        assert_ne!(bytes(&a), bytes(&c));
    }

    #[test]
    fn configurations_respect_limits_and_jaws() {
        let robot = Robot::paper_default();
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let configs = random_configurations(&robot, 2000, &mut rng);
        for q in &configs {
            robot.check_limits(q).unwrap();
        }
        // Uniform: each joint's mean is near the middle of its range.
        for j in 0..N_JOINTS {
            let m = configs.iter().map(|q| q[j]).sum::<f64>() / configs.len() as f64;
            let lim = &robot.config.limits;
            let mid = 0.5 * (lim.q_min_deg[j] + lim.q_max_deg[j]);
            let expect = match j {
                // Rejecting crossed jaws shifts q4 down and q5 up by a third of the half-range.
                3 => mid - (lim.q_max_deg[j] - lim.q_min_deg[j]) / 6.0,
                4 => mid + (lim.q_max_deg[j] - lim.q_min_deg[j]) / 6.0,
                _ => mid,
            };
            assert!((m - expect).abs() < 3.0, "q{} mean {m} expected {expect}", j + 1);
        }
    }

    #[test]
    fn paper_excitation_is_eq16_and_mixed_stays_inside_the_limits() {
        let robot = Robot::paper_default();
        let paper = excitation_commands(&robot, 50, 9, &Excitation::paper()).unwrap();
        assert_eq!(paper, dataset_commands(&robot, 50, 9));
        let mixed = excitation_commands(&robot, 300, 9, &Excitation::mixed()).unwrap();
        assert_eq!(
            mixed,
            excitation_commands(&robot, 300, 9, &Excitation::mixed()).unwrap()
        );
        for q in &mixed {
            robot.check_command_limits(q).expect("inside the command limits");
        }
        // The dither commands the jaws past each other sometimes (as the compensator may), so
        // the models see such commands; eq. (16)'s configurations themselves never cross.
        let crossed = mixed.iter().filter(|q| robot.check_limits(q).is_err()).count();
        assert!(
            crossed > 0 && crossed < mixed.len() / 10,
            "{crossed} crossed of {}",
            mixed.len()
        );
        assert!(paper.iter().all(|q| robot.check_limits(q).is_ok()));
        // It jumps: some consecutive commands are far more than one eq. (16) step apart, and
        // the largest is bounded by four steps plus twice the largest dither on every joint.
        let steps: Vec<f64> = mixed.windows(2).map(|w| dist(&w[0], &w[1])).collect();
        let big = steps.iter().filter(|&&d| d > 2.0 * DATASET_STEP_DEG).count();
        assert!(big > steps.len() / 5, "{big} of {} steps are jumps", steps.len());
        let bound = 4.0 * DATASET_STEP_DEG + 2.0 * 20.0 * (N_JOINTS as f64).sqrt() + 1e-9;
        assert!(steps.iter().all(|&d| d <= bound + DATASET_STEP_DEG));
        let bad = Excitation {
            step_multipliers: vec![0.0],
            dither_deg: vec![0.0],
        };
        assert!(excitation_commands(&robot, 10, 1, &bad)
            .unwrap_err()
            .to_string()
            .contains("multiplier"));
    }
}
