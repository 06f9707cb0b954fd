//! The `preisach` family (configs/plant-preisach.toml): the paper's magnitudes with the joint
//! reaching its range, a bounded friction lag that saturates into one-to-one following, a joint
//! that never moves against its command, the stick–slip loop shape that tells it from Bouc–Wen,
//! the asymmetric branches, the wiping-out (return-point) memory, the delayed slip's time
//! constant, per-unit determinism, and the validation of its table and of its units.

// Loops over joint indices read like the maths they check.
#![allow(clippy::needless_range_loop)]

use crate::common;

use bowden_kinematics::{Robot, N_JOINTS};
use bowden_plant::{ConfigError, FamilyKind, Plant, PlantBuildError, PlantConfig};
use common::{lands_in_the_papers_range, quasi_static_run, state_bytes};

fn file(name: &str) -> String {
    format!("{}/../../configs/{name}", env!("CARGO_MANIFEST_DIR"))
}

fn preisach() -> PlantConfig {
    PlantConfig::load(file("plant-preisach.toml")).unwrap()
}

fn bouc_wen() -> PlantConfig {
    PlantConfig::load(file("plant-boucwen.toml")).unwrap()
}

/// The shipped file without unit variation (the file's nominal parameters) and, optionally,
/// without the delayed slip (rate-independent).
fn nominal(relaxation: bool) -> PlantConfig {
    let mut cfg = preisach();
    cfg.variation.relative_sd = 0.0;
    if !relaxation {
        cfg.preisach.as_mut().unwrap().relaxation_fraction = 0.0;
    }
    cfg
}

/// X = G + L of joint k: the load at which every contact has let go, and the bound on the lag.
fn slide(cfg: &PlantConfig, k: usize) -> f64 {
    let p = cfg.preisach.as_ref().unwrap();
    p.lag_amplitude_deg[k] + p.presliding_deg[k]
}

/// Joint commands with q1 at `q1_deg`, the others at rest (jaws apart).
fn q1_at(q1_deg: f64) -> [f64; N_JOINTS] {
    [q1_deg, 0.0, 0.0, -10.0, 10.0]
}

#[test]
fn preisach_plant_lands_in_the_papers_range() {
    let config = preisach();
    assert_eq!(config.family, FamilyKind::Preisach);
    let r = lands_in_the_papers_range(&config);
    // … with every joint reaching its range less at most its lag (X, plus the unit's variation
    // of up to 15 % and the assembly offset): the robot reaches its workspace.
    let lim = Robot::paper_default().config.limits;
    for (k, j) in r.joints.iter().enumerate() {
        let lag = 1.15 * slide(&config, k) + 1.0;
        assert!(
            j.reach_deg.0 < lim.q_min_deg[k] + lag && j.reach_deg.1 > lim.q_max_deg[k] - lag,
            "{}: reach {:?}",
            j.joint,
            j.reach_deg
        );
    }
}

#[test]
fn a_commanded_joint_reaches_its_command_less_a_bounded_lag() {
    // q1 commanded to ±50° (from rest, and then across): it gets within X = G + L of the
    // command (≥ G + L·|P₀|, the exact bound the module's tests check) less its assembly offset;
    // the lag behind a rising command is G + L·P₀ (≈ 18°), behind a falling one G − L·P₀
    // (≈ 28°).
    let cfg = nominal(false);
    let x = slide(&cfg, 0);
    let offset = cfg.joints.offset_deg[0];
    let robot = Robot::paper_default();
    let mut plant = Plant::new(&robot, &cfg, 1);
    for target in [50.0, -50.0, 50.0] {
        plant.settle_joints(&q1_at(target), 2.0, 0.01).unwrap();
        let q = plant.q_phy_deg()[0] - offset;
        assert!((q - target).abs() <= x, "q1 commanded {target}: {q}");
        assert!(q * target > 0.0 && q.abs() < target.abs(), "q1 commanded {target}: {q}");
    }
}

/// q1 swept 2° at a time from `from` to `to` (commands held 0.5 s each, after a first sweep to
/// `from` so the branch starts with every contact let go the other way): (command, q_phy).
fn branch(config: &PlantConfig, from: f64, to: f64) -> Vec<(f64, f64)> {
    let robot = Robot::paper_default();
    let mut plant = Plant::new(&robot, config, 1);
    let n = ((to - from).abs() / 2.0).round() as i64;
    let step = (to - from) / n as f64;
    let first: Vec<_> = (0..=n / 2).map(|k| q1_at(from * k as f64 / (n / 2) as f64)).collect();
    quasi_static_run(&mut plant, &first);
    let path: Vec<_> = (0..=n).map(|k| q1_at(from + step * k as f64)).collect();
    let phy = quasi_static_run(&mut plant, &path);
    path.iter().zip(&phy).map(|(c, p)| (c[0], p[0])).collect()
}

/// dq_phy/dq_cmd of each 2° step of a branch.
fn slopes(branch: &[(f64, f64)]) -> Vec<f64> {
    branch
        .windows(2)
        .map(|w| (w[1].1 - w[0].1) / (w[1].0 - w[0].0))
        .collect()
}

#[test]
fn past_the_knee_the_joint_follows_its_command_one_to_one() {
    // Once the command has moved on by 2X after a reversal every contact has let go: the lag is
    // constant, dq/dv = 1, the branch parallel to the diagonal, up and down.
    let cfg = nominal(false);
    let x = slide(&cfg, 0);
    for (from, to) in [(-72.0, 72.0), (72.0, -72.0)] {
        let b = branch(&cfg, from, to);
        let s = slopes(&b);
        let past = |c: f64| (c - from).abs() >= 2.0 * x + 2.0;
        let sliding: Vec<_> = (0..s.len()).filter(|&k| past(b[k].0)).collect();
        assert!(sliding.len() > 20, "{from} → {to}");
        for &k in &sliding {
            assert!((s[k] - 1.0).abs() < 2e-3, "{from} → {to}: slope {} at {}", s[k], b[k].0);
        }
        let lag: Vec<f64> = sliding.iter().map(|&k| b[k].0 - b[k].1).collect();
        assert!(
            lag.iter().all(|l| (l - lag[0]).abs() < 0.01),
            "{from} → {to}: lags {lag:?}"
        );
        // Behind the command, by at most X (less the offset).
        let behind = (to - from).signum() * (lag[0] + cfg.joints.offset_deg[0]);
        assert!(behind > 10.0 && behind <= x, "{from} → {to}: lag {}", lag[0]);
    }
}

#[test]
fn after_a_reversal_it_sticks_then_follows_with_a_sharp_knee_unlike_bouc_wen() {
    let cfg = nominal(false);
    let x = slide(&cfg, 0);
    let b = branch(&cfg, -72.0, 72.0);
    let s = slopes(&b);
    let travel = |k: usize| b[k].0 + 72.0;
    // Stuck: over the first 20° after the reversal the joint does not move.
    let first_20 = (b[10].1 - b[0].1).abs();
    // A sharp knee: one 2° step from at most 0.7 to unit slope, at 2X after the reversal.
    let knee = (1..s.len()).find(|&k| s[k] > 0.99).unwrap();
    eprintln!(
        "preisach: {first_20:.3}° over the first 20°, knee {:.3} → {:.3} at {}",
        s[knee - 1],
        s[knee],
        b[knee].0
    );
    assert!(first_20 < 0.05, "stuck after the reversal: {first_20}");
    assert!(s[knee - 1] < 0.7, "knee: {} → {}", s[knee - 1], s[knee]);
    assert!(
        (travel(knee) - 2.0 * x).abs() <= 2.0,
        "knee at {} after the reversal",
        travel(knee)
    );
    // Bouc–Wen over the same sweep: it creeps off at once and rounds into a slope below 1.
    let bw = branch(&bouc_wen(), -72.0, 72.0);
    let bw_first_20 = (bw[10].1 - bw[0].1).abs();
    let bw_s = slopes(&bw);
    let bw_max = bw_s.iter().fold(f64::MIN, |m, &v| m.max(v));
    let bw_jump = bw_s.windows(2).map(|w| w[1] - w[0]).fold(f64::MIN, f64::max);
    eprintln!("bouc-wen: {bw_first_20:.3}° over the first 20°, steepest {bw_max:.3}, largest jump {bw_jump:.3}");
    assert!(bw_first_20 > 0.3, "bouc-wen after the reversal: {bw_first_20}");
    assert!(bw_max < 0.95 && bw_jump < 0.2, "bouc-wen: {bw_max}, {bw_jump}");
}

#[test]
fn the_joint_never_moves_against_nor_outruns_its_command() {
    // A dense seeded random walk of q1 (runs toward random targets, steps back, jumps),
    // quasi-static (no delayed slip), the nominal joint and a varied unit, the other joints
    // held: every step moves the joint the command's way and no further.
    let mut seed = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        (seed >> 11) as f64 / (1u64 << 53) as f64
    };
    let robot = Robot::paper_default();
    for cfg in [nominal(false), {
        let mut c = preisach();
        c.preisach.as_mut().unwrap().relaxation_fraction = 0.0;
        c
    }] {
        let mut plant = Plant::new(&robot, &cfg, 5);
        let (mut c, mut q) = (0.0f64, plant.q_quasi_static_deg()[0]);
        let (mut moved, mut stood, mut target) = (0usize, 0usize, 0.0f64);
        for k in 0..5000 {
            // Toward a random target in steps of up to 4°, now and then a step back or a jump.
            if next() < 0.03 {
                target = (next() - 0.5) * 116.0;
            }
            let r = next();
            let d = if r < 0.1 {
                (next() - 0.5) * 4.0
            } else if r < 0.12 {
                (next() - 0.5) * 60.0
            } else {
                (target - c).clamp(-4.0, 4.0) * next()
            };
            let c_next = (c + d).clamp(-58.0, 58.0);
            plant.step_joints(&q1_at(c_next), 0.01).unwrap();
            let q_next = plant.q_quasi_static_deg()[0];
            let (dc, dq) = (c_next - c, q_next - q);
            assert!(
                dq * dc >= -1e-9,
                "step {k}: command {c} → {c_next}, joint {q} → {q_next}"
            );
            assert!(
                dq.abs() <= dc.abs() + 1e-9,
                "step {k}: command {c} → {c_next}, joint {q} → {q_next}"
            );
            if dq.abs() > 0.5 * dc.abs() {
                moved += 1;
            } else if dq.abs() < 0.01 * dc.abs() {
                stood += 1;
            }
            (c, q) = (c_next, q_next);
        }
        // Both regimes occur: stuck and following.
        assert!(moved > 500 && stood > 500, "{}: moved {moved}, stood {stood}", cfg.name);
    }
}

/// q1's major loop (±68°, 2° commands held 0.5 s, rate-independent, no offset): for each
/// d in 0, 4, …, 56 after the reversal the point-symmetry defect ascending(−68 + d) +
/// descending(68 − d).
fn symmetry_defects(mut cfg: PlantConfig) -> Vec<f64> {
    cfg.joints.offset_deg = [0.0; N_JOINTS];
    let robot = Robot::paper_default();
    let mut plant = Plant::new(&robot, &cfg, 1);
    let path: Vec<_> = (0..=34)
        .chain((-34..34).rev())
        .chain(-33..=34)
        .map(|k| q1_at(2.0 * k as f64))
        .collect();
    let phy = quasi_static_run(&mut plant, &path);
    let bottom = path.iter().position(|q| q[0] == -68.0).unwrap();
    let on = |from: usize, c: f64| {
        (from..path.len())
            .find(|&k| path[k][0] == c)
            .map(|k| phy[k][0])
            .unwrap()
    };
    (0..=14)
        .map(|i| {
            let d = 4.0 * i as f64;
            on(bottom, -68.0 + d) + on(34, 68.0 - d)
        })
        .collect()
}

#[test]
fn ascending_and_descending_branches_differ_in_shape() {
    // On a symmetric density the descending branch is the ascending one turned by 180°: the
    // defect is 0 everywhere.
    let mut symmetric = nominal(false);
    let p = symmetric.preisach.as_mut().unwrap();
    p.interaction_sd_negative_deg = p.interaction_sd_positive_deg;
    let d = symmetry_defects(symmetric);
    assert!(d.iter().all(|v| v.abs() < 0.05), "symmetric density: {d:?}");
    // The file's skewed density (σ₊ ≠ σ₋): not a shift of the loop (a constant defect) but
    // branches of different shapes while the contacts let go.
    let d = symmetry_defects(nominal(false));
    let spread = d.iter().fold(f64::MIN, |m, &v| m.max(v)) - d.iter().fold(f64::MAX, |m, &v| m.min(v));
    eprintln!("skewed density: defects {d:?}");
    assert!(spread > 1.0, "skewed density: defects {d:?}");
}

/// Major path to a turning point (q1: 0 → 50 → −5: a 55° descent, less than 2X, so the
/// contacts keep a memory), then `minor` and back to −5; returns the plant at the turning point
/// (before) and after the minor loop.
fn around_a_minor_loop(config: &PlantConfig, hold_s: f64, minor: &[f64]) -> (Plant, Plant) {
    let robot = Robot::paper_default();
    let mut plant = Plant::new(&robot, config, 1);
    for c in [0.0, 25.0, 50.0, 30.0, 10.0, -5.0] {
        plant.settle_joints(&q1_at(c), hold_s, 0.01).unwrap();
    }
    let before = plant.clone();
    for &c in minor.iter().chain(&[-5.0]) {
        plant.settle_joints(&q1_at(c), hold_s, 0.01).unwrap();
    }
    (before, plant)
}

fn quasi_static_gap(a: &Plant, b: &Plant) -> f64 {
    (0..N_JOINTS)
        .map(|k| (a.q_quasi_static_deg()[k] - b.q_quasi_static_deg()[k]).abs())
        .fold(0.0, f64::max)
}

#[test]
fn minor_loops_are_wiped_out_unlike_bouc_wen() {
    let minor = [3.0, 10.0, 20.0, 13.0, 1.0];
    // Rate-independent: back at the turning point the plant is where it was (the decoded
    // commands of the other joints may differ by the inverse cable equation's last bits, so
    // not bit for bit), and it goes on exactly as if the minor loop had not happened.
    let cfg = nominal(false);
    let (mut before, mut after) = around_a_minor_loop(&cfg, 0.5, &minor);
    let gap = quasi_static_gap(&before, &after);
    assert!(gap < 1e-9, "back at the turning point: {gap}");
    for c in [-20.0, -35.0, 0.0, 30.0] {
        before.settle_joints(&q1_at(c), 0.5, 0.01).unwrap();
        after.settle_joints(&q1_at(c), 0.5, 0.01).unwrap();
        let gap = quasi_static_gap(&before, &after);
        assert!(gap < 1e-9, "q1 = {c}: {gap}");
    }
    // With the delayed slip: the same once each command has relaxed (40 τ).
    let (before, after) = around_a_minor_loop(&nominal(true), 10.0, &minor);
    let gap = quasi_static_gap(&before, &after);
    assert!(gap < 1e-9, "relaxed, back at the turning point: {gap}");
    // The same excursion changes a Bouc–Wen joint: its memory is its present lag, which the
    // minor loop has moved.
    let (before, after) = around_a_minor_loop(&bouc_wen(), 0.5, &minor);
    let gap = quasi_static_gap(&before, &after);
    assert!(gap > 0.3, "bouc-wen after the minor loop: {gap}");
    // And a loop that goes past the last maximum (50) wipes that maximum out instead.
    let (before, after) = around_a_minor_loop(&cfg, 0.5, &[20.0, 56.0, 20.0]);
    let gap = quasi_static_gap(&before, &after);
    assert!(gap > 0.1, "past the last maximum: {gap}");
}

/// The jump q1: 30 → 36 held for 3 s in 1 ms steps (after relaxing at −40 and then at 30: the
/// cable slides, every contact has let go): q_qs of q1 per step and q_phy at the end of each
/// step.
fn held_after_a_jump(config: &PlantConfig) -> (Vec<f64>, Vec<f64>) {
    let robot = Robot::paper_default();
    let mut plant = Plant::new(&robot, config, 1);
    plant.settle_joints(&q1_at(-40.0), 5.0, 0.01).unwrap();
    plant.settle_joints(&q1_at(30.0), 5.0, 0.01).unwrap();
    let (mut qs, mut phy) = (Vec::new(), Vec::new());
    for _ in 0..3000 {
        plant.step_joints(&q1_at(36.0), 0.001).unwrap();
        qs.push(plant.q_quasi_static_deg()[0]);
        phy.push(plant.q_phy_deg()[0]);
    }
    (qs, phy)
}

#[test]
fn a_held_command_creeps_on_with_the_configured_time_constant() {
    let (qs, phy) = held_after_a_jump(&nominal(true));
    // The joint goes on moving long after the settling (τ_settle = 0.08 s) is over.
    let (at_04, at_3) = (phy[399], phy[2999]);
    eprintln!("q1: {} at 1 ms, {at_04} at 0.4 s, {at_3} at 3 s", qs[0]);
    assert!(at_3 - at_04 > 0.3, "creep after 0.4 s: {at_04} → {at_3}");
    // While the cable slides the joint follows the contacts' load one to one, and the load
    // relaxes as e^{−t/τ}: the fraction of the creep done after t − 1 ms is 1 − e^{−(t − 1 ms)/τ},
    // τ = relaxation_time_s = 0.25 s; the creep is the κ = 35 % of the 6° jump not felt at once.
    let total = qs[2999] - qs[0];
    assert!(
        (total - 0.35 * 6.0 * (-0.001f64 / 0.25).exp()).abs() < 1e-3,
        "creep {total}"
    );
    for (t_ms, tau) in [(250, 0.25), (500, 0.25), (125, 0.25)] {
        let done = (qs[t_ms] - qs[0]) / total;
        let want = 1.0 - (-(t_ms as f64 * 1e-3) / tau).exp();
        assert!((done - want).abs() < 0.002, "after {t_ms} ms: {done} vs {want}");
    }
    // Doubling τ stretches the creep in time by exactly 2.
    let mut slow = nominal(true);
    slow.preisach.as_mut().unwrap().relaxation_time_s = 0.5;
    let (qs_slow, _) = held_after_a_jump(&slow);
    for t_ms in [100, 250, 700] {
        let fast_done = (qs[t_ms] - qs[0]) / total;
        let slow_done = (qs_slow[2 * t_ms + 1] - qs_slow[0]) / (qs_slow[2999] - qs_slow[0]);
        assert!(
            (fast_done - slow_done).abs() < 0.01,
            "{t_ms} ms at τ vs {} ms at 2τ: {fast_done} vs {slow_done}",
            2 * t_ms + 1
        );
    }
    // Without the delayed slip the quasi-static state does not move after the step.
    let (still, _) = held_after_a_jump(&nominal(false));
    assert!(still.iter().all(|&q| q == still[0]), "rate-independent when κ = 0");
}

#[test]
fn after_a_reversal_the_held_joint_does_not_creep() {
    // Right after a reversal the contacts' load moves inside their dead bands: nothing to
    // release late. (A linear output relaxation would creep here as well.)
    let robot = Robot::paper_default();
    let mut plant = Plant::new(&robot, &nominal(true), 1);
    plant.settle_joints(&q1_at(30.0), 5.0, 0.01).unwrap();
    plant.step_joints(&q1_at(26.0), 0.001).unwrap();
    let first = plant.q_quasi_static_deg()[0];
    plant.settle_joints(&q1_at(26.0), 3.0, 0.001).unwrap();
    let creep = (plant.q_quasi_static_deg()[0] - first).abs();
    assert!(creep < 0.05, "after a 4° reversal: {creep}");
}

#[test]
fn a_unit_is_reproducible_and_units_differ() {
    let robot = Robot::paper_default();
    let config = preisach();
    let unit = config.variation.unit_for_run(99);
    assert_eq!(unit, 2029);
    let cmds = common::commands(&robot, 8, 4);
    let run = |seed: u64| {
        let mut plant = Plant::new(&robot, &config, seed);
        let (mut bytes, mut q_phy) = (Vec::new(), Vec::new());
        for q in &cmds {
            plant.settle_joints(q, 0.3, 0.01).unwrap();
            bytes.extend(state_bytes(&plant));
            q_phy.push(plant.q_phy_deg());
        }
        (bytes, q_phy)
    };
    let (a, a_phy) = run(unit);
    assert_eq!(a, run(unit).0, "same unit, same bytes");
    let (b, b_phy) = run(unit + 1);
    assert_ne!(a, b, "another unit is another robot");
    // … with other loops, not only other cable tensions: the joints' own lag, contact
    // population and relaxation vary with the unit (q_phy does not depend on the cables'
    // stiffness in this family).
    let differ = (0..N_JOINTS).all(|k| a_phy.iter().zip(&b_phy).any(|(x, y)| (x[k] - y[k]).abs() > 0.05));
    assert!(differ, "every joint's loop varies with the unit");
    // Without variation every unit is the nominal one.
    let mut flat = config.clone();
    flat.variation.relative_sd = 0.0;
    let flat_run = |seed: u64| {
        let mut plant = Plant::new(&robot, &flat, seed);
        plant.settle_joints(&cmds[3], 0.3, 0.01).unwrap();
        state_bytes(&plant)
    };
    assert_eq!(flat_run(1), flat_run(2));
}

#[test]
fn every_unit_of_the_shipped_file_keeps_the_joint_behind_its_command() {
    // The file's margin (L·b ≤ 0.69) covers the unit variation (3σ = 15 %): whichever unit a run
    // picks (the file without its `unit`), its plant builds.
    let robot = Robot::paper_default();
    let mut cfg = preisach();
    cfg.variation.unit = None;
    for seed in 0..300 {
        assert!(Plant::try_new(&robot, &cfg, seed).is_ok(), "unit {seed}");
    }
}

fn parse(text: &str) -> Result<PlantConfig, ConfigError> {
    PlantConfig::parse(text, std::path::Path::new("test/plant.toml"))
}

fn invalid(text: &str) -> (String, String) {
    match parse(text) {
        Err(ConfigError::Invalid { field, problem, .. }) => (field, problem),
        other => panic!("expected an invalid field, got {other:?}"),
    }
}

#[test]
fn a_presliding_travel_beyond_the_bound_is_refused_naming_the_field() {
    let text = std::fs::read_to_string(file("plant-preisach.toml")).unwrap();
    assert!(parse(&text).is_ok());
    // The file's L·b is 0.65 for q1: twice its pre-sliding travel breaks the bound (a bigger X
    // also widens the grid, so b falls a little: 16 gives L·b ≈ 1.1).
    let from = "presliding_deg = [8.0, 8.0";
    assert!(text.contains(from));
    let (field, problem) = invalid(&text.replacen(from, "presliding_deg = [8.0, 16.0", 1));
    assert_eq!(field, "preisach.presliding_deg[1]");
    for want in [
        "L·b",
        "> 1",
        "coercivity_median_deg",
        "interaction_sd_negative_deg",
        "outruns",
    ] {
        assert!(problem.contains(want), "{want}: {problem}");
    }
    // The same travel is fine with a density spread wide enough (b small).
    let spread = text
        .replacen(from, "presliding_deg = [8.0, 16.0", 1)
        .replacen("coercivity_log_sd = 0.8", "coercivity_log_sd = 2.0", 1)
        .replacen(
            "interaction_sd_positive_deg = [18.5, 3.0",
            "interaction_sd_positive_deg = [18.5, 30.0",
            1,
        );
    assert!(parse(&spread).is_ok(), "{:?}", parse(&spread).err());
}

#[test]
fn a_unit_beyond_the_bound_is_a_typed_error_and_a_file_naming_it_is_refused() {
    // A wide unit variation (25 %): some units' pre-sliding travel or density break L·b ≤ 1.
    let robot = Robot::paper_default();
    let mut cfg = preisach();
    cfg.variation.unit = None;
    cfg.variation.relative_sd = 0.25;
    let (seed, e) = (0..200)
        .find_map(|seed| Plant::try_new(&robot, &cfg, seed).err().map(|e| (seed, e)))
        .expect("a unit beyond the bound");
    let PlantBuildError::Preisach { unit, source, .. } = &e else {
        panic!("{e:?}");
    };
    assert_eq!(*unit, seed);
    assert!(source.joint < N_JOINTS && source.product > 1.0, "{source:?}");
    assert!((source.product - source.presliding_deg * source.rate_per_deg).abs() < 1e-12);
    let msg = e.to_string();
    let field = format!("presliding_deg[{}]", source.joint);
    assert!(msg.contains(&field) && msg.contains(&format!("unit {seed}")), "{msg}");
    // The same unit named in the file: refused on load, naming the field.
    cfg.variation.unit = Some(seed);
    let (got, problem) = invalid(&toml::to_string(&cfg).unwrap());
    assert_eq!(got, format!("preisach.{field}"));
    assert!(problem.contains(&format!("unit {seed}")), "{problem}");
    // Other units of it build; `Plant::new` would panic with the same message.
    let ok = (0..200).find(|&s| Plant::try_new(&robot, &cfg, s).is_ok()).unwrap();
    assert_ne!(ok, seed);
}

#[test]
#[should_panic(expected = "presliding_deg")]
fn a_plant_refuses_a_unit_beyond_the_bound() {
    let robot = Robot::paper_default();
    let mut cfg = preisach();
    cfg.variation.unit = None;
    cfg.variation.relative_sd = 0.25;
    let seed = (0..200).find(|&s| Plant::try_new(&robot, &cfg, s).is_err()).unwrap();
    let _ = Plant::new(&robot, &cfg, seed);
}

#[test]
fn bad_density_parameters_are_refused_naming_the_field() {
    let text = std::fs::read_to_string(file("plant-preisach.toml")).unwrap();
    assert!(parse(&text).is_ok());
    let cases: [(&str, &str, &str, &str); 12] = [
        (
            "lag_amplitude_deg = [23.0, 21.0, 18.0",
            "lag_amplitude_deg = [23.0, 21.0, 0.0",
            "preisach.lag_amplitude_deg[2]",
            "[0.1, 90]",
        ),
        (
            "lag_amplitude_deg = [23.0, 21.0, 18.0, 19.0",
            "lag_amplitude_deg = [23.0, 21.0, 18.0, nan",
            "preisach.lag_amplitude_deg[3]",
            "[0.1, 90]",
        ),
        (
            "presliding_deg = [8.0",
            "presliding_deg = [0.0",
            "preisach.presliding_deg[0]",
            "(0, 90]",
        ),
        (
            "coercivity_median_deg = [12.5, 11.5",
            "coercivity_median_deg = [12.5, 40.0",
            "preisach.coercivity_median_deg[1]",
            "presliding_deg[1] = 29",
        ),
        (
            "coercivity_median_deg = [12.5",
            "coercivity_median_deg = [0.0",
            "preisach.coercivity_median_deg[0]",
            "[0.01,",
        ),
        (
            "coercivity_log_sd = 0.8",
            "coercivity_log_sd = 0.0",
            "preisach.coercivity_log_sd",
            "[0.05, 2]",
        ),
        (
            "interaction_sd_positive_deg = [18.5",
            "interaction_sd_positive_deg = [-18.5",
            "preisach.interaction_sd_positive_deg[0]",
            "presliding_deg[0] = 31]",
        ),
        (
            "interaction_sd_negative_deg = [3.0, 17.5, 2.5, 2.5, 15.0]",
            "interaction_sd_negative_deg = [3.0, 17.5, 2.5, 2.5, 70.0]",
            "preisach.interaction_sd_negative_deg[4]",
            "outside the grid",
        ),
        (
            "relaxation_fraction = 0.35",
            "relaxation_fraction = 1.0",
            "preisach.relaxation_fraction",
            "[0, 1)",
        ),
        (
            "relaxation_time_s = 0.25",
            "relaxation_time_s = 0.0",
            "preisach.relaxation_time_s",
            "(0, 60] s",
        ),
        (
            "relaxation_time_s = 0.25",
            "relaxation_time_s = inf",
            "preisach.relaxation_time_s",
            "(0, 60] s",
        ),
        (
            "presliding_deg = [8.0",
            "presliding_deg = [30.0",
            "preisach.presliding_deg[0]",
            "L·b",
        ),
    ];
    for (from, to, field, want) in cases {
        assert!(text.contains(from), "fixture: {from}");
        let changed = text.replacen(from, to, 1);
        let (got, problem) = invalid(&changed);
        assert_eq!(got, field, "{to}");
        assert!(problem.contains(want), "{to}: {problem}");
        let msg = parse(&changed).unwrap_err().to_string();
        assert!(msg.contains("test/plant.toml") && msg.contains(field), "{msg}");
    }

    // The table is required for the family, refused for the others, and closed.
    let start = text.find("\n[preisach]\n").unwrap();
    let end = text.find("\n[dynamics]\n").unwrap();
    let without = format!("{}{}", &text[..start], &text[end..]);
    let (field, problem) = invalid(&without);
    assert_eq!(field, "preisach");
    assert!(problem.contains("required"), "{problem}");
    let capstan = std::fs::read_to_string(file("plant.toml")).unwrap();
    let (field, problem) = invalid(&format!("{capstan}\n{}", &text[start..end]));
    assert_eq!(field, "preisach");
    assert!(problem.contains("preisach") && problem.contains("capstan"), "{problem}");
    let (field, _) = invalid(&format!("{text}\n[hysteresis]\nplays = 6\nthreshold_spread = 0.8\n"));
    assert_eq!(field, "hysteresis");
    for old in [
        "saturation_deg = [20.0, 21.0, 15.0, 19.0, 19.0]",
        "input_range_deg = [64.0, 64.0, 48.0, 54.0, 54.0]",
    ] {
        let e = parse(&text.replacen("[preisach]\n", &format!("[preisach]\n{old}\n"), 1)).unwrap_err();
        let key = old.split(' ').next().unwrap();
        assert!(
            matches!(e, ConfigError::Parse { .. }) && e.to_string().contains(key),
            "{e}"
        );
    }
    // Written back, the file reads the same.
    let cfg = parse(&text).unwrap();
    assert_eq!(parse(&toml::to_string(&cfg).unwrap()).unwrap(), cfg);
}

#[test]
#[should_panic(expected = "without its [preisach] table")]
fn a_plant_refuses_a_preisach_family_without_its_table() {
    let mut cfg = PlantConfig::paper_default();
    cfg.family = FamilyKind::Preisach;
    let _ = Plant::new(&Robot::paper_default(), &cfg, 1);
}
