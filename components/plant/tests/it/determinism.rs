//! Same commands + seed → bit-identical states; another seed → another robot.

use crate::common;

use bowden_kinematics::Robot;
use bowden_plant::{Plant, PlantConfig};
use common::{commands, state_bytes};

fn run(seed: u64, cmds: &[[f64; 5]]) -> Vec<u8> {
    run_config(&PlantConfig::paper_default(), seed, cmds)
}

fn run_config(config: &PlantConfig, seed: u64, cmds: &[[f64; 5]]) -> Vec<u8> {
    let robot = Robot::paper_default();
    let mut plant = Plant::new(&robot, config, seed);
    let mut trace = Vec::new();
    for q in cmds {
        let w = robot.cables().displacements_mm(q);
        // A mix of fine steps and a settle, as the runtime and the dataset protocol use.
        for _ in 0..3 {
            plant.step(&w, 0.001).unwrap();
            trace.extend(state_bytes(&plant));
        }
        plant.settle(&w, 0.1, 0.007).unwrap();
        trace.extend(state_bytes(&plant));
    }
    trace
}

#[test]
fn two_runs_give_identical_bytes() {
    let robot = Robot::paper_default();
    let cmds = commands(&robot, 30, 5);
    let a = run(42, &cmds);
    let b = run(42, &cmds);
    assert!(!a.is_empty());
    assert_eq!(a, b, "same seed and commands must give the same bytes");
    let c = run(43, &cmds);
    assert_ne!(a, c, "another seed is another plant instance");
}

/// The same for the other hysteresis families: a seed is one manufactured unit of each.
#[test]
fn every_family_is_deterministic_per_unit() {
    let robot = Robot::paper_default();
    let cmds = commands(&robot, 12, 5);
    for file in ["plant-boucwen.toml", "plant-lugre.toml", "plant-preisach.toml"] {
        let config = PlantConfig::load(format!("{}/../../configs/{file}", env!("CARGO_MANIFEST_DIR"))).unwrap();
        let a = run_config(&config, 42, &cmds);
        assert_eq!(a, run_config(&config, 42, &cmds), "{file}: same seed, same bytes");
        assert_ne!(
            a,
            run_config(&config, 43, &cmds),
            "{file}: another seed is another unit"
        );
        // Reset and clones replay the same way.
        let mut plant = Plant::new(&robot, &config, 7);
        let mut first = Vec::new();
        for q in &cmds[..6] {
            plant.settle_joints(q, 0.2, 0.01).unwrap();
            first.extend(state_bytes(&plant));
        }
        let mut clone = plant.clone();
        plant.reset();
        assert_eq!(plant.t_sim_ns(), 0);
        let mut second = Vec::new();
        for q in &cmds[..6] {
            plant.settle_joints(q, 0.2, 0.01).unwrap();
            second.extend(state_bytes(&plant));
        }
        assert_eq!(first, second, "{file}: reset replays");
        for q in &cmds[6..] {
            plant.settle_joints(q, 0.2, 0.01).unwrap();
            clone.settle_joints(q, 0.2, 0.01).unwrap();
            assert_eq!(state_bytes(&plant), state_bytes(&clone), "{file}: clones");
        }
    }
}

#[test]
fn reset_replays_identically() {
    let robot = Robot::paper_default();
    let cmds = commands(&robot, 10, 9);
    let mut plant = Plant::new(&robot, &PlantConfig::paper_default(), 1);
    let initial = state_bytes(&plant);
    let mut first = Vec::new();
    for q in &cmds {
        plant.settle_joints(q, 0.5, 0.01).unwrap();
        first.extend(state_bytes(&plant));
    }
    assert_ne!(state_bytes(&plant), initial);
    plant.reset();
    assert_eq!(state_bytes(&plant), initial);
    assert_eq!(plant.t_sim_ns(), 0);
    let mut second = Vec::new();
    for q in &cmds {
        plant.settle_joints(q, 0.5, 0.01).unwrap();
        second.extend(state_bytes(&plant));
    }
    assert_eq!(first, second);
}

#[test]
fn clones_evolve_identically() {
    let robot = Robot::paper_default();
    let cmds = commands(&robot, 8, 2);
    let mut a = Plant::new(&robot, &PlantConfig::paper_default(), 7);
    for q in &cmds[..cmds.len() / 2] {
        a.settle_joints(q, 0.2, 0.01).unwrap();
    }
    let mut b = a.clone();
    for q in &cmds[cmds.len() / 2..] {
        a.settle_joints(q, 0.2, 0.01).unwrap();
        b.settle_joints(q, 0.2, 0.01).unwrap();
        assert_eq!(state_bytes(&a), state_bytes(&b));
    }
}

/// A plant file names its manufactured unit: runs of any seed simulate that unit; without it
/// the run's seed picks the unit. The shipped robots are units (their models were trained on
/// them), and a malformed unit is refused with the file and field named.
#[test]
fn the_plant_file_names_its_unit() {
    let shipped = PlantConfig::paper_default();
    assert_eq!(shipped.variation.unit, Some(2026));
    assert_eq!(shipped.variation.unit_for_run(1), 2026);
    assert_eq!(shipped.variation.unit_for_run(99), 2026);
    let text = include_str!("../../../../configs/plant.toml");
    let p = std::path::Path::new("plant.toml");
    let free = PlantConfig::parse(&text.replace("unit = 2026", ""), p).unwrap();
    assert_eq!(free.variation.unit_for_run(7), 7);
    let e = PlantConfig::parse(&text.replace("unit = 2026", "unit = -4"), p)
        .unwrap_err()
        .to_string();
    assert!(e.contains("plant.toml") && e.contains("unit"), "{e}");
    let robot2 = PlantConfig::parse(include_str!("../../../../configs/plant-robot2.toml"), p).unwrap();
    assert_eq!(robot2.variation.unit, Some(79));
}
