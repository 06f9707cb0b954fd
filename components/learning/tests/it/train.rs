//! Training: paper parameter counts and block counts, the split, learning, determinism,
//! and the candle backend agreeing with the fused one.

use bowden_learning::arch::{tcn_num_blocks, Architecture, Direction, ModelSpec, TcnBlock};
use bowden_learning::synthetic::hysteretic_dataset;
use bowden_learning::train::{train, TrainConfig};
use bowden_learning::windows::{PhySource, SplitConfig, WindowSet};

#[test]
fn paper_parameter_counts_at_l80_j5() {
    let count = |a| ModelSpec::new(a, 80, 5, TcnBlock::ReluLinear).param_count();
    assert_eq!(count(Architecture::Tcn), 800);
    assert_eq!(count(Architecture::Lstm), 77_701);
    assert_eq!(count(Architecture::TcnLstm), 78_501);
    // FNN 5L → 128 → 128 → 5 (the fixture README's 68,485).
    assert_eq!(count(Architecture::Fnn), 68_485);
    // Both block variants have the same parameters.
    assert_eq!(
        ModelSpec::new(Architecture::Tcn, 80, 5, TcnBlock::ReluRelu).param_count(),
        800
    );
}

#[test]
fn eq20_block_counts_for_the_paper_lengths() {
    let blocks: Vec<usize> = [10, 50, 65, 80, 100, 120].into_iter().map(tcn_num_blocks).collect();
    assert_eq!(blocks, vec![2, 4, 5, 5, 5, 5]);
    assert_eq!(
        ModelSpec::new(Architecture::Tcn, 50, 5, TcnBlock::ReluLinear).param_count(),
        4 * 160
    );
}

#[test]
fn split_shares_no_sample_between_train_and_validation() {
    let ds = hysteretic_dataset(3000, 5, 1);
    for (l, blocks) in [(10, 1), (80, 1), (80, 4), (120, 3)] {
        let split = SplitConfig {
            val_fraction: 0.2,
            val_blocks: blocks,
        };
        let w = WindowSet::build(&ds, Direction::Forward, l, split, PhySource::Vision).unwrap();
        let mut owner = vec![0u8; ds.len()]; // 1 = train, 2 = val
        for (ids, tag) in [(&w.train, 1u8), (&w.val, 2u8)] {
            for &t in ids {
                let (a, b) = w.span(t);
                for (s, o) in owner.iter_mut().enumerate().take(b + 1).skip(a) {
                    assert!(*o == 0 || *o == tag, "L={l} blocks={blocks}: sample {s} in both splits");
                    *o = tag;
                }
            }
        }
        // Every window is somewhere: train, validation, or purged (it straddles a boundary;
        // at most L − 1 per boundary).
        assert_eq!(w.train.len() + w.val.len() + w.purged, ds.len());
        assert!(w.purged <= (2 * blocks) * (l - 1));
        let val_samples = 0.2 * ds.len() as f64;
        let n_val = w.val.len() as f64;
        assert!(
            n_val <= val_samples + blocks as f64,
            "L={l}: {n_val} validation windows"
        );
        assert!(
            n_val >= val_samples - (blocks * l) as f64,
            "L={l}: {n_val} validation windows"
        );
    }
}

#[test]
fn windows_pad_with_zero_degrees_and_normalise_inside() {
    let ds = hysteretic_dataset(400, 3, 2);
    let w = WindowSet::build(&ds, Direction::Inverse, 10, SplitConfig::default(), PhySource::Truth).unwrap();
    // Window of target 2: 7 rows of padding (0°), then samples 0, 1, 2.
    let raw = w.window_deg(2);
    assert!(raw[..7 * 3].iter().all(|&v| v == 0.0));
    let q_true = ds.q_true_deg.as_ref().unwrap();
    assert_eq!(&raw[7 * 3..], &q_true[..9]);
    let norm = w.window(2);
    for k in 0..3 {
        assert_eq!(norm[k], w.norm_in.apply(k, 0.0));
        assert_eq!(norm[7 * 3 + k], w.norm_in.apply(k, q_true[k]));
    }
    // Inverse: the target is the command.
    assert_eq!(w.target(5)[1], w.norm_out.apply(1, ds.q_cmd_deg[5 * 3 + 1]));
}

fn small_config(arch: Architecture, epochs: usize) -> TrainConfig {
    let mut cfg = TrainConfig::paper(arch, Direction::Forward, 16, epochs, 7);
    cfg.threads = 2;
    cfg
}

#[test]
fn short_training_lowers_validation_loss() {
    let ds = hysteretic_dataset(2500, 5, 3);
    let w = WindowSet::build(&ds, Direction::Forward, 16, SplitConfig::default(), PhySource::Vision).unwrap();
    for arch in [Architecture::Tcn, Architecture::Fnn] {
        let out = train(&w, &small_config(arch, 6), None).unwrap();
        let first = &out.epochs[0];
        let best = out.best();
        assert!(
            best.val_loss < 0.3 * out.initial_val_loss && best.val_loss < first.val_loss,
            "{arch}: validation loss {} (untrained) → {} (epoch 1) → {} (best)",
            out.initial_val_loss,
            first.val_loss,
            best.val_loss
        );
        assert!(out.epochs.last().unwrap().train_loss < first.train_loss);
        // Better than the raw hysteresis (the identity model q_phy = q_cmd).
        let identity = bowden_learning::windows::overall_rmse(&w.identity_rmse_deg(&w.val));
        assert!(
            best.val_rmse_deg < identity,
            "{arch}: {} ≥ identity {identity}",
            best.val_rmse_deg
        );
    }
}

#[test]
fn lstm_learns_too() {
    let ds = hysteretic_dataset(1200, 5, 4);
    let w = WindowSet::build(&ds, Direction::Forward, 8, SplitConfig::default(), PhySource::Vision).unwrap();
    let mut cfg = TrainConfig::paper(Architecture::Lstm, Direction::Forward, 8, 4, 1);
    cfg.threads = 2;
    let out = train(&w, &cfg, None).unwrap();
    assert!(
        out.best().val_loss < 0.5 * out.initial_val_loss,
        "{} → {:?}",
        out.initial_val_loss,
        out.epochs
    );
}

#[test]
fn same_seed_same_bits_whatever_the_thread_count() {
    let ds = hysteretic_dataset(1500, 5, 5);
    let w = WindowSet::build(&ds, Direction::Inverse, 12, SplitConfig::default(), PhySource::Vision).unwrap();
    let mut cfg = TrainConfig::paper(Architecture::TcnLstm, Direction::Inverse, 12, 2, 9);
    cfg.threads = 1;
    let a = train(&w, &cfg, None).unwrap();
    cfg.threads = 2;
    let b = train(&w, &cfg, None).unwrap();
    assert_eq!(a.model.params, b.model.params);
    assert_eq!(a.epochs[1].val_loss, b.epochs[1].val_loss);
    cfg.seed = 10;
    let c = train(&w, &cfg, None).unwrap();
    assert_ne!(a.model.params, c.model.params);
}

/// The same with mixed precision, whose step runs the optimiser on both threads, prepares
/// only what a mixed step reads and accumulates per time step: still the same bits with one
/// thread or two, and validation (an f32 pass) sees the current weights.
#[test]
fn mixed_precision_same_bits_whatever_the_thread_count() {
    let ds = hysteretic_dataset(1500, 5, 5);
    let w = WindowSet::build(&ds, Direction::Inverse, 12, SplitConfig::default(), PhySource::Vision).unwrap();
    for arch in [Architecture::Lstm, Architecture::TcnLstm] {
        let mut cfg = TrainConfig::paper(arch, Direction::Inverse, 12, 2, 9);
        cfg.precision = bowden_learning::kernels::Precision::Bf16;
        cfg.threads = 1;
        let a = train(&w, &cfg, None).unwrap();
        cfg.threads = 2;
        let b = train(&w, &cfg, None).unwrap();
        assert_eq!(a.model.params, b.model.params, "{arch}");
        assert_eq!(a.epochs[1].val_loss, b.epochs[1].val_loss, "{arch}");
        // Validation ran on the current weights (an f32 pass needs the f32 copies the
        // mixed steps skip): the best epoch's RMSE is the exported model's own.
        let own = bowden_learning::train::rmse_deg(&a.model, &w, &w.val).unwrap();
        assert_eq!(own, a.best().val_rmse_deg, "{arch}");
        let mut f32_cfg = cfg.clone();
        f32_cfg.precision = bowden_learning::kernels::Precision::F32;
        let f = train(&w, &f32_cfg, None).unwrap();
        assert_ne!(a.model.params, f.model.params, "{arch}: bf16 trained the f32 bits");
        let rel = (a.best().val_rmse_deg - f.best().val_rmse_deg).abs() / f.best().val_rmse_deg;
        assert!(
            rel < 0.1,
            "{arch}: bf16 {} vs f32 {}",
            a.best().val_rmse_deg,
            f.best().val_rmse_deg
        );
    }
}

#[test]
fn early_stopping_stops() {
    let ds = hysteretic_dataset(800, 5, 6);
    let w = WindowSet::build(&ds, Direction::Forward, 10, SplitConfig::default(), PhySource::Vision).unwrap();
    let mut cfg = small_config(Architecture::Tcn, 200);
    cfg.seq_len = 10;
    cfg.lr = 0.05; // large enough to stall quickly
    cfg.early_stop = Some(3);
    let out = train(&w, &cfg, None).unwrap();
    assert!(out.stopped_early && out.epochs.len() < 200);
    assert_eq!(out.epochs.len(), out.best_epoch + 3);
}

/// Needs candle: `cargo test -p bowden-learning --features candle`.
#[cfg(feature = "candle")]
#[test]
fn candle_backend_follows_the_same_trajectory() {
    // Same init, same batches: after a few Adam steps the two backends agree closely.
    let ds = hysteretic_dataset(300, 5, 8);
    for arch in [Architecture::Tcn, Architecture::Lstm] {
        let l = 6;
        let w = WindowSet::build(&ds, Direction::Forward, l, SplitConfig::default(), PhySource::Vision).unwrap();
        let mut cfg = TrainConfig::paper(arch, Direction::Forward, l, 1, 3);
        cfg.batch_size = 64;
        let fused = train(&w, &cfg, None).unwrap();
        cfg.backend = bowden_learning::train::Backend::Candle;
        let candle = train(&w, &cfg, None).unwrap();
        let worst = fused
            .model
            .params
            .iter()
            .zip(&candle.model.params)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        // 4 Adam steps of lr 1e-3 move a weight by ≤ 4e-3; the backends agree far closer.
        assert!(worst < 2e-4, "{arch}: fused and candle parameters differ by {worst}");
        let (vf, vc) = (fused.epochs[0].val_rmse_deg, candle.epochs[0].val_rmse_deg);
        assert!((vf - vc).abs() < 1e-3 * vf, "{arch}: val RMSE {vf} vs {vc}");
    }
}

/// L2-SP (`TrainConfig::anchor`): a fine-tune on a changed robot's data moves the weights
/// less the stronger the pull towards the starting ones, and still fits the new data better
/// than the starting model; the weight must come with starting weights and be ≥ 0.
#[test]
fn an_anchored_fine_tune_stays_nearer_its_start() {
    use bowden_learning::fine_tune;
    let windows = |n: usize, seed: u64| {
        WindowSet::build(
            &hysteretic_dataset(n, 3, seed),
            Direction::Forward,
            16,
            SplitConfig::default(),
            PhySource::Vision,
        )
        .unwrap()
    };
    let start = train(&windows(1500, 3), &small_config(Architecture::Tcn, 4), None)
        .unwrap()
        .model;
    // Another unit of the same design: its data under the start's normalisation.
    let new = windows(600, 11)
        .with_normalisers(start.norm_in.clone(), start.norm_out.clone())
        .unwrap();
    let dist = |p: &[f32]| -> f64 {
        p.iter()
            .zip(&start.params)
            .map(|(a, b)| ((a - b) as f64).powi(2))
            .sum::<f64>()
            .sqrt()
    };
    let mut cfg = small_config(Architecture::Tcn, 6);
    cfg.lr = 3e-3;
    let free = fine_tune(&new, &cfg, &start, None).unwrap();
    cfg.anchor = 3.0;
    let anchored = fine_tune(&new, &cfg, &start, None).unwrap();
    let (d_free, d_anchored) = (dist(&free.model.params), dist(&anchored.model.params));
    assert!(
        d_anchored < 0.5 * d_free,
        "distance from the start: free {d_free:.4}, anchored {d_anchored:.4}"
    );
    assert!(
        anchored.best().val_rmse_deg < anchored.initial_val_rmse_deg,
        "anchored fine-tune: {} → {}",
        anchored.initial_val_rmse_deg,
        anchored.best().val_rmse_deg
    );
    cfg.anchor = -1.0;
    assert!(fine_tune(&new, &cfg, &start, None).is_err());
    cfg.anchor = f64::NAN;
    assert!(fine_tune(&new, &cfg, &start, None).is_err());
    cfg.anchor = 1.0;
    assert!(train(&new, &cfg, None).is_err(), "an anchor without starting weights");
}
