//! The fused kernels against candle's autograd, live (`--features candle`), and the writer of
//! the stored references the default build holds them to (`reference.rs`).
#![cfg(feature = "candle")]

use crate::kernels_vs_reference::{assert_matches, fused};
use crate::reference::{self, Case, Reference};
use bowden_learning::candle_ref::CandleModel;

fn candle(c: &Case) -> Reference {
    let (params, x, y) = reference::inputs(c);
    let mut cm = CandleModel::from_params(c.spec, &params).unwrap();
    let conv1d_out = c.spec.arch.has_tcn().then(|| {
        cm.conv1d_op = true;
        let o = cm.predict(&x, c.b).unwrap();
        cm.conv1d_op = false;
        o
    });
    let out = cm.predict(&x, c.b).unwrap();
    let (loss, grad) = cm.loss_and_grads(&x, &y, c.b).unwrap();
    Reference {
        loss: loss as f64,
        out,
        grad,
        conv1d_out,
    }
}

#[test]
fn fused_kernels_match_candle_live() {
    for c in reference::cases().iter().filter(|c| !c.name.starts_with("portable_")) {
        assert_matches(c, &fused(c), &candle(c));
    }
}

#[test]
fn the_stored_references_are_candles() {
    for c in reference::cases() {
        let (live, stored) = (candle(&c), reference::load(&c));
        assert_matches(&c, &stored, &live);
    }
}

/// Rewrites `tests/data/candle/*.npy` (after a change to the cases or to candle).
#[test]
#[ignore]
fn write_candle_references() {
    for c in reference::cases() {
        reference::store(&c, &candle(&c));
    }
}
