//! Models written by `bowden-learning` load in `bowden-compensator` exactly as the PyTorch
//! fixtures do: the contract is accepted, the TCN is recognised for the incremental
//! evaluator, and the compensator's numbers are the trained model's.

use bowden_learning::arch::{Architecture, Direction, TcnBlock};
use bowden_learning::synthetic::hysteretic_dataset;
use bowden_learning::train::{train, TrainConfig};
use bowden_learning::windows::{PhySource, SplitConfig, WindowSet};
use bowden_learning::ModelFile;

fn trained(arch: Architecture, block: TcnBlock, direction: Direction, l: usize) -> (ModelFile, WindowSet) {
    let ds = hysteretic_dataset(1200, 5, 4);
    let w = WindowSet::build(&ds, direction, l, SplitConfig::default(), PhySource::Vision).unwrap();
    let mut cfg = TrainConfig::paper(arch, direction, l, 2, 3);
    cfg.tcn_block = block;
    (train(&w, &cfg, None).unwrap().model, w)
}

#[test]
fn exported_models_load_in_the_compensator() {
    let tmp = tempfile::tempdir().unwrap();
    for (arch, block, direction, l) in [
        (Architecture::Tcn, TcnBlock::ReluLinear, Direction::Forward, 80),
        (Architecture::Tcn, TcnBlock::ReluRelu, Direction::Inverse, 50),
        (Architecture::Lstm, TcnBlock::ReluLinear, Direction::Forward, 10),
        (Architecture::Fnn, TcnBlock::ReluLinear, Direction::Inverse, 10),
    ] {
        let (model, w) = trained(arch, block, direction, l);
        let path = tmp.path().join(format!("{arch}_{direction}_{l}.onnx"));
        model.save(&path).unwrap();
        let loaded = bowden_compensator::Model::load(&path)
            .unwrap_or_else(|e| panic!("{arch} {direction} L={l}: the compensator rejects it: {e}"));
        assert_eq!((loaded.seq_len(), loaded.joints()), (l, 5));
        // Every architecture bowden exports runs on the exact incremental evaluator (the LSTM's
        // head reads the final hidden state Y_h, which the recogniser maps to the last column).
        assert!(
            loaded.is_incremental(),
            "{arch} {block}: not recognised: {:?}",
            loaded.unrecognised_reason()
        );
        if let Some(d) = loaded.load_check_max_abs_diff_deg() {
            assert!(d <= 1e-4, "{arch}: compensator's own load check {d}");
        }
        for &t in w.val.iter().step_by(97).take(5) {
            let window: Vec<f32> = w.window_deg(t).iter().map(|&v| v as f32).collect();
            let ours = model.predict_deg(&window, 1);
            let theirs = loaded.eval_full(&window).unwrap();
            for (a, b) in ours.iter().zip(&theirs) {
                assert!(
                    (a - b).abs() <= 1e-4,
                    "{arch} {direction} L={l}: {a} vs compensator {b}"
                );
            }
        }
    }
}
