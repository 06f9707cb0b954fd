//! `tune` on a small seeded hysteretic dataset with briefly trained models: the settings come
//! from validation data only, reproduce bit for bit, and the written config loads.

use bowden_compensator::{ControllerConfig, Mode};
use bowden_kinematics::Robot;
use bowden_learning::arch::{Architecture, Direction};
use bowden_learning::synthetic::hysteretic_dataset;
use bowden_learning::train::{train, TrainConfig};
use bowden_learning::windows::{PhySource, SplitConfig, WindowSet};
use bowden_tuning::{command_spacing_deg, config_toml, tune, TuneError, TuneOptions};
use std::path::{Path, PathBuf};

fn model(ds: &bowden_learning::Dataset, arch: Architecture, d: Direction, dir: &Path) -> PathBuf {
    let l = 20;
    let w = WindowSet::build(ds, d, l, SplitConfig::default(), PhySource::Vision).unwrap();
    let mut cfg = TrainConfig::paper(arch, d, l, 3, 1);
    cfg.threads = 2;
    let m = train(&w, &cfg, None).unwrap().model;
    let p = dir.join(format!("{arch}_{d}.onnx"));
    m.save(&p).unwrap();
    p
}

fn base() -> (String, ControllerConfig) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs/controller.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    let cfg = ControllerConfig::parse(&text, &path).unwrap();
    (text, cfg)
}

#[test]
fn settings_come_from_validation_data_and_reproduce_bit_for_bit() {
    let tmp = tempfile::tempdir().unwrap();
    // The synthetic joints span ±50°; the robot's limits are narrower, which the compensator's
    // clamp handles exactly as on a robot.
    let ds = hysteretic_dataset(1500, 5, 9);
    let fwd = vec![
        model(&ds, Architecture::Tcn, Direction::Forward, tmp.path()),
        model(&ds, Architecture::Fnn, Direction::Forward, tmp.path()),
    ];
    let inv = vec![model(&ds, Architecture::Tcn, Direction::Inverse, tmp.path())];
    let (text, base) = base();
    let robot = Robot::paper_default();
    let opts = TuneOptions {
        max_steps: 120,
        prior_weights: vec![0.0, 1.0],
        ..TuneOptions::default()
    };
    let mut calls = 0;
    let a = tune(&ds, &fwd, &inv, &base, &robot, &opts, &mut |_, _| calls += 1).unwrap();
    let b = tune(&ds, &fwd, &inv, &base, &robot, &opts, &mut |_, _| {}).unwrap();
    let r = &a.report;
    // 2 forward × 1 inverse × (paper + newton at μ ∈ {0, 1, σf/σi}) + 2 uncalibrated references.
    assert_eq!(r.candidates.len(), 2 * 4, "{:#?}", r.candidates);
    assert_eq!(calls, r.candidates.len() + 2);
    // Each forward model's candidates are judged by the other one.
    assert_eq!(r.judges, vec![vec![1], vec![0]]);
    assert_eq!(r.replayed_steps, 120);
    assert!(r.candidates.iter().all(|c| c.judged_rmse_deg.is_finite()));

    // The history step is the training commands' median spacing: eq. (16)'s 3·√5 here.
    let split = WindowSet::build(&ds, Direction::Forward, 1, SplitConfig::default(), PhySource::Vision).unwrap();
    let spacing = command_spacing_deg(&ds, &split.train).unwrap();
    assert!((spacing - 3.0 * 5f64.sqrt()).abs() < 1e-6, "{spacing}");
    assert_eq!(r.step_deg, spacing);

    // The choice: the lowest judged error, and only if it beats the targets sent unchanged.
    match r.chosen {
        Some(k) => {
            let best = &r.candidates[k];
            assert!(r.candidates.iter().all(|c| c.judged_rmse_deg >= best.judged_rmse_deg));
            assert!(best.judged_rmse_deg < r.uncalibrated_judged_rmse_deg[best.forward]);
            assert_eq!(a.config.mode.as_str(), best.mode);
        }
        None => assert_eq!(a.config.mode, Mode::Uncalibrated),
    }
    assert!(a.config.safety.never_worse && a.config.safety.support);

    // Bit for bit.
    let ta = config_toml(&text, &a, "f.onnx", "i.onnx").unwrap();
    let tb = config_toml(&text, &b, "f.onnx", "i.onnx").unwrap();
    assert_eq!(ta, tb);
    assert_eq!(
        serde_json::to_string(&a.report).unwrap(),
        serde_json::to_string(&b.report).unwrap()
    );
    // The file loads as a controller config with the chosen values.
    let cfg = ControllerConfig::parse(&ta, &tmp.path().join("c.toml")).unwrap();
    assert_eq!(cfg.mode, a.config.mode);
    assert_eq!(cfg.history.step_deg, spacing);
    assert_eq!(cfg.newton.prior_weight, a.config.newton.prior_weight);
    assert!(ta.starts_with("# Controller settings chosen by `bowden tune`"));

    // The base's tip rating is replayed and written; without it the key is not written at all,
    // so configs tuned before it existed keep their bytes.
    assert!(!ta.contains("never_worse_tip"), "{ta}");
    let tip_text = text.replace("never_worse = true", "never_worse = true\nnever_worse_tip = true");
    let tip_base = ControllerConfig::parse(&tip_text, Path::new("tip.toml")).unwrap();
    let t = tune(&ds, &fwd, &inv, &tip_base, &robot, &opts, &mut |_, _| {}).unwrap();
    assert!(t.config.safety.never_worse_tip);
    let tt = config_toml(&tip_text, &t, "f.onnx", "i.onnx").unwrap();
    assert!(
        ControllerConfig::parse(&tt, &tmp.path().join("t.toml"))
            .unwrap()
            .safety
            .never_worse_tip
    );

    // A judge-only model (one too slow for the cycle) rates the only forward model's candidates.
    let solo = TuneOptions {
        judges: vec![fwd[1].clone()],
        ..opts.clone()
    };
    let c = tune(&ds, &fwd[..1], &inv, &base, &robot, &solo, &mut |_, _| {}).unwrap();
    assert_eq!(c.report.judges, vec![vec![1]]);
    assert_eq!(c.report.judge_only.len(), 1);
    // The same judge on the same candidates: the scores of forward #0's candidates above.
    for (x, y) in c.report.candidates.iter().zip(&a.report.candidates) {
        assert_eq!(x.judged_rmse_deg, y.judged_rmse_deg);
    }

    // With a judge-only model and several forward models, the judge rates every candidate (one
    // yardstick), the forward models do not rate each other.
    let both = tune(&ds, &fwd, &inv, &base, &robot, &solo, &mut |_, _| {}).unwrap();
    assert_eq!(both.report.judges, vec![vec![2], vec![2]]);
    // Forward #0's candidates: the same judge as in the single-forward run, the same scores.
    for (x, y) in both.report.candidates.iter().zip(&c.report.candidates) {
        assert_eq!((x.forward, x.judged_rmse_deg), (y.forward, y.judged_rmse_deg));
    }
}

#[test]
fn wrong_inputs_are_named() {
    let tmp = tempfile::tempdir().unwrap();
    let ds = hysteretic_dataset(600, 5, 2);
    let f = model(&ds, Architecture::Fnn, Direction::Forward, tmp.path());
    let i = model(&ds, Architecture::Fnn, Direction::Inverse, tmp.path());
    let (_, base) = base();
    let robot = Robot::paper_default();
    let opts = TuneOptions::default();
    // An inverse model passed as forward.
    let e = tune(
        &ds,
        std::slice::from_ref(&i),
        std::slice::from_ref(&i),
        &base,
        &robot,
        &opts,
        &mut |_, _| {},
    )
    .err()
    .unwrap();
    assert!(matches!(e, TuneError::Direction { .. }), "{e}");
    assert!(e.to_string().contains("fnn_inverse.onnx"), "{e}");
    let e = tune(&ds, &[], std::slice::from_ref(&i), &base, &robot, &opts, &mut |_, _| {})
        .err()
        .unwrap();
    assert!(e.to_string().contains("no forward model"), "{e}");
    let bad = TuneOptions {
        prior_weights: vec![f64::NAN],
        ..TuneOptions::default()
    };
    let e = tune(
        &ds,
        std::slice::from_ref(&f),
        std::slice::from_ref(&i),
        &base,
        &robot,
        &bad,
        &mut |_, _| {},
    )
    .err()
    .unwrap();
    assert!(e.to_string().contains("prior weight"), "{e}");
}
