//! Excitation while working (`[dither]`): a small zero-mean perturbation added to the command
//! so the (command, estimate) pairs online adaptation gathers while the robot tracks cover a
//! little more than the path itself (docs/architecture.md, "Online adaptation").
//!
//! A new offset is drawn each time the target has moved `step_deg` (the models' history step
//! by default) and held until the next: one offset per history entry, so the models see it as
//! they see a dataset's commands, not as jitter between control periods. Each offset is uniform
//! in ±`amplitude_deg` per joint, then scaled down until the tip it moves, by the robot's
//! kinematics (eq. 3), is at most `max_tip_mm` away from where the undithered command puts it:
//! the bound on the added tip motion. Draws are seeded (ChaCha8): lockstep runs reproduce.
//! Allocation-free.

use bowden_interfaces::model::MAX_JOINTS;
use bowden_kinematics::{Robot, N_JOINTS};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Deserialize;

/// `[dither]` of the controller config. Absent = off.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DitherConfig {
    pub enabled: bool,
    /// Largest offset per joint, deg.
    pub amplitude_deg: f64,
    /// Largest tip displacement an offset may cause, mm (the bound on the added tip motion).
    pub max_tip_mm: f64,
    /// Target motion between two draws, deg (Euclidean, joint space); 0 = the history step.
    pub step_deg: f64,
    pub seed: u64,
}

impl Default for DitherConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            amplitude_deg: 1.0,
            max_tip_mm: 0.5,
            step_deg: 0.0,
            seed: 1,
        }
    }
}

impl DitherConfig {
    pub fn check(&self) -> Result<(), (&'static str, String, &'static str)> {
        if !(self.amplitude_deg.is_finite() && self.amplitude_deg > 0.0 && self.amplitude_deg <= 10.0) {
            return Err((
                "dither.amplitude_deg",
                self.amplitude_deg.to_string(),
                "must be in (0, 10]",
            ));
        }
        if !(self.max_tip_mm.is_finite() && self.max_tip_mm > 0.0 && self.max_tip_mm <= 10.0) {
            return Err(("dither.max_tip_mm", self.max_tip_mm.to_string(), "must be in (0, 10]"));
        }
        if !(self.step_deg.is_finite() && self.step_deg >= 0.0) {
            return Err(("dither.step_deg", self.step_deg.to_string(), "must be ≥ 0"));
        }
        Ok(())
    }
}

/// The dither generator of one compensator.
pub struct Dither {
    cfg: DitherConfig,
    robot: Robot,
    rng: ChaCha8Rng,
    step_deg: f64,
    anchor: [f64; N_JOINTS],
    has_anchor: bool,
    current: [f64; MAX_JOINTS],
    draws: u64,
    scaled: u64,
    max_tip_seen_mm: f64,
}

impl Dither {
    /// `history_step_deg`: the models' history step, used when `step_deg` is 0.
    pub fn new(cfg: &DitherConfig, robot: &Robot, history_step_deg: f64) -> Self {
        Self {
            step_deg: if cfg.step_deg > 0.0 {
                cfg.step_deg
            } else {
                history_step_deg
            },
            rng: ChaCha8Rng::seed_from_u64(cfg.seed ^ 0xd17e_d17e),
            cfg: cfg.clone(),
            robot: robot.clone(),
            anchor: [0.0; N_JOINTS],
            has_anchor: false,
            current: [0.0; MAX_JOINTS],
            draws: 0,
            scaled: 0,
            max_tip_seen_mm: 0.0,
        }
    }

    /// The offset for target `q_des` (5 joints), deg: a new draw when the target has moved
    /// `step_deg` since the last one, else the current offset. A non-finite target gives 0.
    pub fn update(&mut self, q_des: &[f64]) -> &[f64] {
        if q_des.len() != N_JOINTS || !q_des.iter().all(|v| v.is_finite()) {
            self.current = [0.0; MAX_JOINTS];
            return &self.current[..q_des.len().min(MAX_JOINTS)];
        }
        let moved = (0..N_JOINTS)
            .map(|k| (q_des[k] - self.anchor[k]).powi(2))
            .sum::<f64>()
            .sqrt();
        if !self.has_anchor || moved >= self.step_deg {
            self.anchor.copy_from_slice(q_des);
            self.has_anchor = true;
            self.draw(q_des);
        }
        &self.current[..N_JOINTS]
    }

    fn draw(&mut self, q: &[f64]) {
        let a = self.cfg.amplitude_deg;
        let mut d = [0.0f64; N_JOINTS];
        for v in &mut d {
            *v = self.rng.random_range(-a..=a);
        }
        let q0: [f64; N_JOINTS] = core::array::from_fn(|k| q[k]);
        let p0 = self.robot.fk(&q0).ee.translation.vector;
        let tip = |d: &[f64; N_JOINTS]| {
            let q1: [f64; N_JOINTS] = core::array::from_fn(|k| q0[k] + d[k]);
            (self.robot.fk(&q1).ee.translation.vector - p0).norm()
        };
        let mut moved = tip(&d);
        // Scale to the bound; the map is nearly linear at these sizes, and the loop makes the
        // bound exact where it is not.
        let mut scaled = false;
        for _ in 0..16 {
            if moved <= self.cfg.max_tip_mm {
                break;
            }
            let s = 0.99 * self.cfg.max_tip_mm / moved;
            d.iter_mut().for_each(|v| *v *= s);
            moved = tip(&d);
            scaled = true;
        }
        if moved > self.cfg.max_tip_mm {
            d = [0.0; N_JOINTS];
            moved = 0.0;
        }
        self.current = [0.0; MAX_JOINTS];
        self.current[..N_JOINTS].copy_from_slice(&d);
        self.draws += 1;
        self.scaled += scaled as u64;
        self.max_tip_seen_mm = self.max_tip_seen_mm.max(moved);
    }

    /// `(draws, draws scaled down to the tip bound, largest tip displacement of an offset, mm)`.
    pub fn counts(&self) -> (u64, u64, f64) {
        (self.draws, self.scaled, self.max_tip_seen_mm)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn offsets_stay_within_the_tip_bound_and_change_per_step() {
        let robot = Robot::paper_default();
        let cfg = DitherConfig {
            enabled: true,
            amplitude_deg: 5.0,
            max_tip_mm: 0.3,
            ..Default::default()
        };
        let mut d = Dither::new(&cfg, &robot, 6.7);
        let mut q = [10.0, -5.0, 8.0, 3.0, -3.0];
        let first: Vec<f64> = d.update(&q).to_vec();
        // A small move keeps the offset.
        q[0] += 1.0;
        assert_eq!(d.update(&q), &first[..]);
        let mut seen = 0.0f64;
        for k in 0..200 {
            q[k % 3] += if k % 2 == 0 { 7.0 } else { -7.0 };
            let off: [f64; 5] = core::array::from_fn(|i| d.update(&q)[i]);
            let q1: [f64; 5] = core::array::from_fn(|i| q[i] + off[i]);
            let moved = (robot.fk(&q1).ee.translation.vector - robot.fk(&q).ee.translation.vector).norm();
            assert!(moved <= 0.3 + 1e-12, "offset {off:?} moves the tip {moved} mm");
            seen = seen.max(off.iter().fold(0.0, |m, v| m.max(v.abs())));
        }
        let (draws, scaled, max_tip) = d.counts();
        assert_eq!(draws, 201);
        assert!(scaled > 0 && max_tip <= 0.3 && seen > 0.0);
        // The same seed, the same offsets.
        let mut e = Dither::new(&cfg, &robot, 6.7);
        assert_eq!(e.update(&[10.0, -5.0, 8.0, 3.0, -3.0]), &first[..]);
    }

    #[test]
    fn bad_settings_are_named() {
        let c = DitherConfig {
            max_tip_mm: 0.0,
            ..Default::default()
        };
        assert_eq!(c.check().unwrap_err().0, "dither.max_tip_mm");
    }
}
