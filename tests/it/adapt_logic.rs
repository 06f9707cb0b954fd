//! The adaptation logic without processes, on rows from the simulated robot itself (commands of
//! eq. 16, angles by simulator truth): a slip makes the models stale and a validated fine-tune
//! is swapped in; a fine-tune on corrupted rows is refused and nothing is published; the state
//! survives a restart; the compensator's loader refuses a file whose hash or content is wrong.

use bowden_adapt::{AdaptConfig, Adapter, Decision, RowError};
use bowden_compensator::swap::{prepare, LoaderSettings};
use bowden_compensator::{EvaluatorChoice, LoadOptions};
use bowden_interfaces::{fnv1a64, ModelUpdate};
use bowden_kinematics::Robot;
use bowden_plant::{Plant, PlantConfig};
use std::path::{Path, PathBuf};

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn models() -> (PathBuf, PathBuf) {
    (
        root().join("models/tcn_forward_L80.onnx"),
        root().join("models/tcn_inverse_L80.onnx"),
    )
}

/// Index of the first row measured after the slip, and `n` rows of (command, truth): each command
/// held 0.5 s (the paper's pace) on the default robot whose cable w3 slips 0.5 mm at 100 s.
/// (command, physical angles) of one held point, deg.
type Row = ([f64; 5], [f64; 5]);

fn rows(n: usize) -> (usize, Vec<Row>) {
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(root().join("configs/plant-slack-slip.toml"))
        .unwrap()
        .replace("at_s = 120.0", "at_s = 100.0");
    let path = dir.path().join("plant.toml");
    std::fs::write(&path, text).unwrap();
    let robot = Robot::paper_default();
    let mut plant = Plant::new(&robot, &PlantConfig::load(&path).unwrap(), 1);
    let cmds = bowden_trajectory::dataset::dataset_commands(&robot, n, 11);
    let out: Vec<_> = cmds
        .iter()
        .take(n)
        .map(|q| {
            plant.settle_joints(q, 0.5, 0.1).unwrap();
            (*q, plant.q_phy_deg())
        })
        .collect();
    assert_eq!(out.len(), n);
    (200, out)
}

fn config() -> AdaptConfig {
    AdaptConfig::load(&root().join("configs/adapt.toml")).unwrap()
}

#[test]
fn a_slip_is_adapted_to_and_a_corrupted_fine_tune_is_refused() {
    let (slip, rows) = rows(420);
    let (fwd, inv) = models();

    // Clean rows: reference before the slip, then a validated fine-tune after it.
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("clean");
    let mut a = Adapter::open(config(), &state, &fwd, &inv, false).unwrap();
    let mut decisions = Vec::new();
    for (i, (c, p)) in rows.iter().enumerate() {
        a.push(i as u64, c, p, None).unwrap();
        if a.due() {
            let r = a.job().run();
            decisions.push((i, r.record.decision, r.record.fwd_before_deg, r.record.fwd_after_deg));
            a.apply(r, i as u64).unwrap();
        }
    }
    assert_eq!(decisions[0].1, Decision::Reference, "{decisions:?}");
    assert!(decisions[0].0 < slip);
    let swapped: Vec<_> = decisions.iter().filter(|d| d.1 == Decision::Swapped).collect();
    assert!(!swapped.is_empty(), "no fine-tune was swapped in: {decisions:?}");
    assert!(swapped.iter().all(|d| d.0 >= slip), "{decisions:?}");
    let first = swapped[0];
    assert!(
        first.3 < first.2,
        "the swapped forward model must validate better: {first:?}"
    );
    assert!(a.generation() >= 1);
    let cur = a.current().unwrap().clone();
    assert!(cur.dir.join("fwd.onnx").exists() && cur.dir.join("inv.onnx").exists());
    assert!(state.join("state.json").exists() && state.join("adapt.jsonl").exists());

    // A restart goes on where it stopped.
    let (g, n_rows) = (a.generation(), a.rows());
    drop(a);
    let b = Adapter::open(config(), &state, &fwd, &inv, true).unwrap();
    assert_eq!((b.generation(), b.rows()), (g, n_rows));
    assert_eq!(b.current().unwrap().dir, cur.dir);
    // ... and `resume = false` starts afresh.
    let c = Adapter::open(config(), &state, &fwd, &inv, false).unwrap();
    assert_eq!((c.generation(), c.rows()), (0, 0));

    // Corrupted rows after the slip (a camera knocked 10° off on every joint), then clean ones
    // to validate on: the fine-tune learns the corruption, validates worse, is refused.
    let state = dir.path().join("corrupt");
    let mut a = Adapter::open(config(), &state, &fwd, &inv, false).unwrap();
    let mut last = None;
    for (i, (c, p)) in rows.iter().enumerate().take(slip + 160) {
        let mut p = *p;
        if (slip..slip + 110).contains(&i) {
            p.iter_mut().for_each(|v| *v += 10.0);
        }
        a.push(i as u64, c, &p, None).unwrap();
        // Checks before the slip only, then one at the end (its hold-out: the clean rows).
        if (a.due() && i < slip) || i + 1 == slip + 160 {
            let r = a.job().run();
            last = Some(r.record.clone());
            a.apply(r, i as u64).unwrap();
        }
    }
    let last = last.unwrap();
    assert_ne!(last.decision, Decision::Swapped, "{last:?}");
    assert_eq!(
        last.decision,
        Decision::Rejected,
        "the check must have fine-tuned: {last:?}"
    );
    assert!(last.fwd_after_deg >= last.fwd_before_deg * 0.95, "{last:?}");
    assert_eq!(a.generation(), 0);
    assert!(!state.join("gen-0001").exists());
    let log = std::fs::read_to_string(state.join("adapt.jsonl")).unwrap();
    assert!(log.contains("\"rejected\""), "{log}");
}

#[test]
fn bad_rows_are_refused_and_counted() {
    let (fwd, inv) = models();
    let dir = tempfile::tempdir().unwrap();
    let mut a = Adapter::open(config(), dir.path(), &fwd, &inv, false).unwrap();
    assert_eq!(
        a.push(0, &[0.0; 5], &[f64::NAN, 0.0, 0.0, 0.0, 0.0], None),
        Err(RowError::NonFinite { tick: 0 })
    );
    assert!(matches!(
        a.push(1, &[0.0; 4], &[0.0; 4], None),
        Err(RowError::Joints {
            tick: 1,
            cmd: 4,
            phy: 4,
            models: 5
        })
    ));
    a.push(2, &[0.0; 5], &[0.0; 5], None).unwrap();
    // Standing still: skipped.
    a.push(3, &[0.1; 5], &[0.0; 5], None).unwrap();
    assert_eq!((a.rejected_rows(), a.skipped_rows(), a.rows()), (2, 1, 1));
    // A window too short for L = 80 is refused at start.
    let bad = AdaptConfig {
        window_rows: 100,
        ..config()
    };
    let e = Adapter::open(bad, &dir.path().join("x"), &fwd, &inv, false)
        .err()
        .unwrap();
    assert!(
        e.to_string().contains("adapt.window_rows") && e.to_string().contains("100 is too small"),
        "{e}"
    );
    // A malformed settings file names the key.
    let e = AdaptConfig::from_toml("[adapt]\nholdout_fraction = 1.5\n", "test.toml").unwrap_err();
    assert!(e.to_string().contains("holdout_fraction"), "{e}");
    let e = AdaptConfig::from_toml("[adapt]\nwindw_rows = 10\n", "test.toml").unwrap_err();
    assert!(e.to_string().contains("windw_rows"), "{e}");
    let e = AdaptConfig::from_toml("[adapt]\nanchor = -0.5\n", "test.toml").unwrap_err();
    assert!(e.to_string().contains("anchor"), "{e}");
    for bad in ["0.0", "1.5", "nan"] {
        let e = AdaptConfig::from_toml(&format!("[adapt]\ninterpolate = {bad}\n"), "test.toml").unwrap_err();
        assert!(e.to_string().contains("interpolate"), "{bad}: {e}");
    }
}

#[test]
fn the_loader_refuses_a_changed_or_cut_short_file() {
    let (fwd, _) = models();
    let dir = tempfile::tempdir().unwrap();
    let bytes = std::fs::read(&fwd).unwrap();
    std::fs::write(dir.path().join("fwd.onnx"), &bytes).unwrap();
    let settings = LoaderSettings {
        load: LoadOptions::default(),
        fwd_l: 80,
        inv_l: 80,
        joints: 5,
        evaluator: EvaluatorChoice::Auto,
        who: "test".into(),
        verbose: true,
    };
    let mut u = ModelUpdate {
        generation: 7,
        fwd_hash: fnv1a64(&bytes),
        ..Default::default()
    };
    assert!(u.set_dir(dir.path().to_str().unwrap()));
    let ok = prepare(&settings, &u).unwrap();
    assert_eq!(ok.generation, 7);
    assert!(ok.fwd.is_some() && ok.inv.is_none());
    // Announced with another hash: the file changed after the announcement.
    let wrong = ModelUpdate {
        fwd_hash: u.fwd_hash ^ 1,
        ..u
    };
    let e = prepare(&settings, &wrong).unwrap_err();
    assert!(e.to_string().contains("content hash"), "{e}");
    // Cut short, announced with the short file's hash: the load check refuses it.
    std::fs::write(dir.path().join("fwd.onnx"), &bytes[..bytes.len() / 2]).unwrap();
    let short = ModelUpdate {
        fwd_hash: fnv1a64(&bytes[..bytes.len() / 2]),
        ..u
    };
    let e = prepare(&settings, &short).unwrap_err();
    assert!(e.to_string().contains("fwd.onnx"), "{e}");
    // A model of another length than the running one.
    let other = LoaderSettings {
        fwd_l: 50,
        ..settings.clone()
    };
    std::fs::write(dir.path().join("fwd.onnx"), &bytes).unwrap();
    let e = prepare(&other, &u).unwrap_err();
    assert!(e.to_string().contains("L = 50"), "{e}");
    // A relative directory is refused.
    let mut rel = u;
    assert!(rel.set_dir("relative/dir"));
    assert!(prepare(&settings, &rel)
        .unwrap_err()
        .to_string()
        .contains("not absolute"));
}
