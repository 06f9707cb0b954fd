//! Safe refinement (docs/architecture.md, "Safe refinement") on purpose with poor models: the
//! paper's protocol cut short (eq. 16 commands only, 30 epochs, a few hundred configurations)
//! on robots of every hysteresis family bowden simulates. Each calibrated mode with the
//! shipped refinement settings and `[safety]` on must track no worse than sending the targets
//! unchanged, by the plant's truth: in joint MAE with the shipped joint rating, and in joint
//! MAE, tip position and tip orientation with `never_worse_tip`.
//!
//! The data is recorded on the plant directly (truth, no camera) so the test stays short; the
//! vision loop is exercised by `bench transfer` and `tests/it/evaluate_short.rs`.

use bowden_compensator::{Compensator, ControllerConfig, Mode, SafetyConfig, StepOutput};
use bowden_kinematics::{JointsDeg, Robot, N_JOINTS};
use bowden_learning::arch::{Architecture, Direction};
use bowden_learning::dataset::Dataset;
use bowden_learning::spacing::{auto_decimation, AUTO_DECIMATION};
use bowden_learning::train::{train, TrainConfig};
use bowden_learning::windows::{PhySource, SplitConfig, WindowSet};
use bowden_plant::{Plant, PlantConfig};
use std::path::{Path, PathBuf};

const PAUSE_S: f64 = 0.5;
const DT_S: f64 = 0.01;

fn repo(p: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(p)
}

/// The paper's dataset protocol on `plant`, measured by truth.
fn record(plant: &mut Plant, commands: &[JointsDeg]) -> Dataset {
    let n = commands.len();
    let mut ds = Dataset {
        joints: N_JOINTS,
        t_ns: Vec::with_capacity(n),
        q_cmd_deg: Vec::with_capacity(n * N_JOINTS),
        q_phy_deg: Vec::with_capacity(n * N_JOINTS),
        q_true_deg: None,
        valid: vec![true; n],
    };
    for q in commands {
        plant.settle_joints(q, PAUSE_S, DT_S).unwrap();
        ds.t_ns.push(plant.t_sim_ns() as i64);
        ds.q_cmd_deg.extend_from_slice(q);
        ds.q_phy_deg.extend_from_slice(&plant.q_phy_deg());
    }
    ds
}

/// A poor model pair: eq. (16) only, 30 epochs, the shipped architecture (TCN, L = 80), with
/// histories decimated by up to `decimation` samples per model step.
fn poor_pair(ds: &Dataset, dir: &Path, tag: &str, decimation: usize) -> (PathBuf, PathBuf) {
    let mut out = Vec::new();
    for d in [Direction::Forward, Direction::Inverse] {
        let mut w = WindowSet::build(ds, d, 80, SplitConfig::default(), PhySource::Vision).unwrap();
        w.set_decimation(decimation).unwrap();
        let mut cfg = TrainConfig::paper(Architecture::Tcn, d, 80, 30, 7);
        cfg.threads = 2;
        cfg.decimation = decimation;
        let m = train(&w, &cfg, None).unwrap().model;
        assert!(m.support.is_some(), "train records the data's support");
        let p = dir.join(format!("{tag}_d{decimation}_{d}.onnx"));
        m.save(&p).unwrap();
        out.push(p);
    }
    (out[0].clone(), out[1].clone())
}

/// Errors (truth) of holding each target's command for the paper's pause, and the largest
/// |q_cmd − q_desired| sent.
#[derive(Debug, Clone, Copy)]
struct Tracked {
    /// Joint MAE, deg.
    joint_deg: f64,
    /// Mean tip position error, mm.
    pos_mm: f64,
    /// Mean tip orientation error, deg.
    rot_deg: f64,
    /// Largest |q_cmd − q_desired|, deg.
    gap_deg: f64,
}

impl Tracked {
    /// The metrics where `self` is worse than `base`, named.
    fn worse_than(&self, base: &Tracked) -> Vec<String> {
        let mut v = Vec::new();
        for (what, a, b) in [
            ("joint MAE", self.joint_deg, base.joint_deg),
            ("tip position", self.pos_mm, base.pos_mm),
            ("tip orientation", self.rot_deg, base.rot_deg),
        ] {
            if a > b {
                v.push(format!("{what} {a:.3} > {b:.3}"));
            }
        }
        v
    }
}

fn track(plant: &mut Plant, comp: Option<&mut Compensator>, targets: &[JointsDeg]) -> Tracked {
    plant.reset();
    let robot = plant.robot().clone();
    let mut out = StepOutput::default();
    let (mut sum, mut pos, mut rot, mut gap) = (0.0, 0.0, 0.0, 0.0f64);
    let mut comp = comp;
    for q_d in targets {
        let cmd: JointsDeg = match comp.as_deref_mut() {
            Some(c) => {
                c.step(q_d, &mut out).unwrap();
                core::array::from_fn(|k| out.q_cmd_deg[k])
            }
            None => *q_d,
        };
        for k in 0..N_JOINTS {
            gap = gap.max((cmd[k] - q_d[k]).abs());
        }
        let cmd = robot.clamp_command_to_limits(&cmd);
        plant.settle_joints(&cmd, PAUSE_S, DT_S).unwrap();
        let q = plant.q_phy_deg();
        sum += (0..N_JOINTS).map(|k| (q[k] - q_d[k]).abs()).sum::<f64>();
        let (p, r) = bowden_kinematics::pose_distance(&robot.fk(q_d).ee, &robot.fk(&q).ee);
        pos += p;
        rot += r;
    }
    let n = targets.len() as f64;
    Tracked {
        joint_deg: sum / (n * N_JOINTS as f64),
        pos_mm: pos / n,
        rot_deg: rot / n,
        gap_deg: gap,
    }
}

fn controller(fwd: &Path, inv: &Path, mode: Mode, safety: SafetyConfig) -> ControllerConfig {
    let mut c = ControllerConfig::shipped();
    c.mode = mode;
    c.model_fwd = Some(fwd.to_path_buf());
    c.model_inv = Some(inv.to_path_buf());
    c.budget.budget_ns = 0; // lockstep: the result must not depend on the machine
    c.output.rate_limit_deg_s = 0.0; // held targets, not a 1 kHz stream
    c.safety = safety;
    c
}

/// Errors (truth) per (mode, safety variant), and uncalibrated, on one plant file.
struct FamilyResult {
    plant: String,
    uncalibrated: Tracked,
    /// (mode, variant index, errors)
    runs: Vec<(Mode, usize, Tracked)>,
}

/// Which histories a variant's models are trained on.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Histories {
    /// Consecutive samples only: the paper's training, taken literally.
    Consecutive,
    /// What `bowden train` does by default (`--decimation auto`): decimated, on eq. (16) data.
    Auto,
}

fn run_family(plant_file: &str, tmp: &Path, variants: &[(Histories, SafetyConfig)]) -> FamilyResult {
    let robot = Robot::paper_default();
    let cfg = PlantConfig::load(repo(plant_file)).unwrap();
    let mut plant = Plant::new(&robot, &cfg, cfg.variation.unit_for_run(5));
    let commands = bowden_trajectory::dataset_commands(&robot, 220, 11);
    let ds = record(&mut plant, &commands);
    let tag = Path::new(plant_file)
        .file_stem()
        .unwrap()
        .to_string_lossy()
        .into_owned();
    let rows = WindowSet::build(&ds, Direction::Forward, 1, SplitConfig::default(), PhySource::Vision)
        .unwrap()
        .train;
    let auto = auto_decimation(&ds, &rows).unwrap();
    assert_eq!(
        auto.decimation, AUTO_DECIMATION,
        "eq. (16) data are single-step: {auto}"
    );
    let mut pairs: Vec<(Histories, (PathBuf, PathBuf))> = Vec::new();
    // Unseen targets: another seed's eq. (16) path (one model step apart).
    let targets = bowden_trajectory::dataset_commands(&robot, 12, 99);
    let uncalibrated = track(&mut plant, None, &targets);
    let mut r = FamilyResult {
        plant: plant_file.into(),
        uncalibrated,
        runs: Vec::new(),
    };
    for mode in [Mode::Paper, Mode::Newton] {
        for (v, (histories, safety)) in variants.iter().enumerate() {
            if !pairs.iter().any(|(h, _)| h == histories) {
                let decimation = match histories {
                    Histories::Consecutive => 1,
                    Histories::Auto => auto.decimation,
                };
                pairs.push((*histories, poor_pair(&ds, tmp, &tag, decimation)));
            }
            let (fwd, inv) = &pairs.iter().find(|(h, _)| h == histories).unwrap().1;
            let mut comp = Compensator::from_config(&controller(fwd, inv, mode, safety.clone()), &robot).unwrap();
            let t = track(&mut plant, Some(&mut comp), &targets);
            r.runs.push((mode, v, t));
        }
    }
    r
}

const FAMILIES: [&str; 4] = [
    "configs/plant.toml",
    "configs/plant-robot2.toml",
    "configs/plant-boucwen.toml",
    "configs/plant-lugre.toml",
];

#[test]
fn poor_models_never_track_worse_than_uncalibrated_on_any_family() {
    let tmp = tempfile::tempdir().unwrap();
    let mut failures = Vec::new();
    let shipped = ControllerConfig::shipped().safety;
    assert!(
        shipped.never_worse && shipped.support,
        "the shipped config runs the safe refinement"
    );
    let tip = SafetyConfig {
        never_worse_tip: true,
        ..shipped.clone()
    };
    for plant_file in FAMILIES {
        let r = run_family(
            plant_file,
            tmp.path(),
            &[
                (Histories::Consecutive, shipped.clone()),
                (Histories::Consecutive, SafetyConfig::default()),
                (Histories::Consecutive, tip.clone()),
                (Histories::Auto, shipped.clone()),
            ],
        );
        let u = r.uncalibrated;
        eprintln!(
            "{}: uncalibrated joint MAE {:.2}°, tip {:.2} mm / {:.2}°",
            r.plant, u.joint_deg, u.pos_mm, u.rot_deg
        );
        for (mode, v, t) in &r.runs {
            let what = [
                "shipped [safety]",
                "no safety",
                "shipped + tip rating",
                "train's default (decimated) models, shipped [safety]",
            ][*v];
            eprintln!(
                "  {mode} {what}: {:.2}°, {:.2} mm / {:.2}° (largest correction {:.1}°)",
                t.joint_deg, t.pos_mm, t.rot_deg, t.gap_deg
            );
            // The shipped joint rating bounds the joints; with the tip rating the tip is bounded
            // too. (The joint rating alone let paper mode's tip orientation on the Bouc–Wen
            // robot end 4 % worse than uncalibrated here: 25.15° against 24.20°.)
            let checked = match v {
                0 => t
                    .worse_than(&u)
                    .into_iter()
                    .filter(|w| w.starts_with("joint"))
                    .collect(),
                2 | 3 => t.worse_than(&u),
                _ => Vec::new(),
            };
            for w in checked {
                failures.push(format!("{}: {mode} {what}: {w} (uncalibrated)", r.plant));
            }
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// The study behind the shipped `[safety]` values (a benchmark, not a test: `cargo test
/// --release --test it safe_refinement:: -- --ignored --nocapture`). Units: each plant file's
/// configured unit, which `bench transfer` keeps for tuning and never reports on.
#[test]
#[ignore]
fn safety_variants_on_poor_models() {
    let tmp = tempfile::tempdir().unwrap();
    let mut variants = Vec::new();
    for step_scale in [0.0, 1.0, 2.0, 3.0] {
        for correction_scale in [0.0, 1.0] {
            variants.push(SafetyConfig {
                step_scale,
                correction_scale,
                ..SafetyConfig::on()
            });
        }
    }
    variants.push(SafetyConfig {
        never_worse_tip: true,
        ..SafetyConfig::on()
    });
    variants.push(SafetyConfig {
        never_worse: true,
        ..SafetyConfig::default()
    });
    variants.push(SafetyConfig::default());
    for plant_file in FAMILIES {
        let variants: Vec<_> = variants.iter().map(|s| (Histories::Consecutive, s.clone())).collect();
        let r = run_family(plant_file, tmp.path(), &variants);
        let u = r.uncalibrated;
        println!(
            "{}: uncalibrated {:.2}°, {:.2} mm / {:.2}°",
            r.plant, u.joint_deg, u.pos_mm, u.rot_deg
        );
        for (mode, v, t) in &r.runs {
            let s = &variants[*v].1;
            println!(
                "  {mode:7} support {} step×{} guard×{} never_worse {} tip {}: {:.2}°, {:.2} mm / {:.2}° ({:.1}°)",
                s.support,
                s.step_scale,
                s.correction_scale,
                s.never_worse,
                s.never_worse_tip,
                t.joint_deg,
                t.pos_mm,
                t.rot_deg,
                t.gap_deg
            );
        }
    }
}
