//! The fused kernels against candle's autograd: same outputs, same loss, same gradients, for
//! every architecture and both TCN block variants. Held to the stored candle results
//! (`reference.rs`); with `--features candle`, `kernels_vs_candle` also compares with candle
//! live and can rewrite them.

use crate::reference::{self, Case, Reference};
use bowden_learning::arch::{Architecture, ModelSpec, TcnBlock};
use bowden_learning::kernels::Net;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn random(n: usize, scale: f32, rng: &mut ChaCha8Rng) -> Vec<f32> {
    (0..n).map(|_| rng.random_range(-scale..scale)).collect()
}

/// The fused kernels' loss, output and gradient for a case.
pub fn fused(c: &Case) -> Reference {
    let (params, x, y) = reference::inputs(c);
    let (spec, b) = (c.spec, c.b);
    let net = Net::new(spec);
    let prep = net.prepared(&params);
    let mut ws = net.workspace(b);
    let mut out = vec![0.0; b * spec.joints];
    net.forward(&params, &prep, &x, b, &mut ws, &mut out);
    let mut grad = vec![0.0; net.param_count()];
    let scale = 2.0 / (b * spec.joints) as f32;
    let sse = net.forward_backward(&params, &prep, &x, &y, b, scale, &mut ws, &mut grad);
    Reference {
        loss: sse / (b * spec.joints) as f64,
        out,
        grad,
        conv1d_out: None,
    }
}

/// Holds `got` to `want` with the tolerances of f32 kernels against f32 autograd.
pub fn assert_matches(c: &Case, got: &Reference, want: &Reference) {
    let tag = format!("{} ({} {} L={})", c.name, c.spec.arch, c.spec.tcn_block, c.spec.seq_len);
    let max_diff = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
    if let Some(conv) = &want.conv1d_out {
        // candle's own conv1d (pad_with_zeros + padding 0) gives the same forward pass.
        let err = max_diff(&got.out, conv);
        assert!(err < 2e-5, "{tag}: conv1d forward differs by {err}");
    }
    let out_err = max_diff(&got.out, &want.out);
    assert!(out_err < 2e-5, "{tag}: outputs differ by {out_err}");
    assert!(
        ((got.loss - want.loss) / want.loss).abs() < 1e-5,
        "{tag}: loss {} vs candle {}",
        got.loss,
        want.loss
    );
    let gmax = want.grad.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    assert!(gmax > 0.0, "{tag}: candle gradient is all zero");
    for t in &c.spec.layout().tensors {
        let r = t.range();
        let err = max_diff(&got.grad[r.clone()], &want.grad[r.clone()]);
        let tmax = want.grad[r].iter().fold(0.0f32, |m, v| m.max(v.abs()));
        assert!(
            err <= 1e-4 * gmax.max(1e-3) && err <= 1e-3 * tmax.max(1e-6) + 1e-6,
            "{tag}: gradient of {} differs by {err} (tensor max {tmax}, global max {gmax})",
            t.name
        );
    }
}

#[test]
fn fused_kernels_match_candle_for_every_architecture() {
    let cases = reference::cases();
    for c in cases.iter().filter(|c| !c.name.starts_with("portable_")) {
        assert_matches(c, &fused(c), &reference::load(c));
    }
}

#[test]
fn a_wrong_kernel_would_be_caught() {
    // The check is not vacuous: one gradient entry off by 1 % of the largest fails it.
    let c = reference::case("lstm");
    let want = reference::load(&c);
    let mut got = fused(&c);
    let gmax = want.grad.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    got.grad[3] += 0.01 * gmax;
    let r = std::panic::catch_unwind(|| assert_matches(&c, &got, &want));
    assert!(r.is_err());
}

#[test]
fn shards_sum_to_the_full_batch_gradient() {
    let spec = ModelSpec::new(Architecture::TcnLstm, 10, 5, TcnBlock::ReluLinear);
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let params = spec.init_params(11);
    let b = 8;
    let x = random(b * 10 * 5, 1.0, &mut rng);
    let y = random(b * 5, 1.0, &mut rng);
    let net = Net::new(spec);
    let prep = net.prepared(&params);
    let scale = 2.0 / (b * 5) as f32;
    let mut ws = net.workspace(b);
    let mut full = vec![0.0; net.param_count()];
    net.forward_backward(&params, &prep, &x, &y, b, scale, &mut ws, &mut full);
    let mut sharded = vec![0.0; net.param_count()];
    let (h, xl) = (3, 3 * 10 * 5);
    net.forward_backward(&params, &prep, &x[..xl], &y[..h * 5], h, scale, &mut ws, &mut sharded);
    net.forward_backward(
        &params,
        &prep,
        &x[xl..],
        &y[h * 5..],
        b - h,
        scale,
        &mut ws,
        &mut sharded,
    );
    let gmax = full.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    for (a, b) in full.iter().zip(&sharded) {
        assert!((a - b).abs() <= 1e-5 * gmax);
    }
}

/// Mixed precision (bf16 operands, f32 sums in the LSTM's recurrent products) against the
/// f32 kernels on the same batch: the forward pass outside training is f32 in both (same
/// bits), the loss and every gradient tensor agree to bf16's precision, and they are not the
/// f32 numbers (so the bf16 path did run).
#[test]
fn lstm_mixed_precision_gradients_follow_f32() {
    use bowden_learning::kernels::Precision;
    for (spec, b, seed) in [
        (ModelSpec::new(Architecture::Lstm, 80, 5, TcnBlock::ReluLinear), 16, 21),
        (ModelSpec::new(Architecture::Lstm, 9, 3, TcnBlock::ReluLinear), 5, 22),
        (
            ModelSpec::new(Architecture::TcnLstm, 12, 5, TcnBlock::ReluLinear),
            4,
            23,
        ),
    ] {
        let tag = format!("{} L={} b={b}", spec.arch, spec.seq_len);
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let params = spec.init_params(seed);
        let x = random(b * spec.seq_len * spec.joints, 1.5, &mut rng);
        let y = random(b * spec.joints, 1.0, &mut rng);
        let scale = 2.0 / (b * spec.joints) as f32;
        let run = |precision: Precision| {
            let net = Net::new(spec).with_precision(precision);
            let prep = net.prepared(&params);
            let mut ws = net.workspace(b);
            let mut out = vec![0.0; b * spec.joints];
            net.forward(&params, &prep, &x, b, &mut ws, &mut out);
            let mut grad = vec![0.0; net.param_count()];
            let sse = net.forward_backward(&params, &prep, &x, &y, b, scale, &mut ws, &mut grad);
            (out, sse, grad)
        };
        let (out32, sse32, g32) = run(Precision::F32);
        let (out16, sse16, g16) = run(Precision::Bf16);
        assert_eq!(out32, out16, "{tag}: the forward pass outside training must stay f32");
        assert!(
            ((sse16 - sse32) / sse32).abs() < 1e-2,
            "{tag}: loss {sse16} vs f32 {sse32}"
        );
        assert_ne!(g32, g16, "{tag}: the bf16 path gave the f32 gradient bit for bit");
        for t in &spec.layout().tensors {
            let r = t.range();
            let norm = |g: &[f32]| g.iter().map(|v| (*v as f64).powi(2)).sum::<f64>().sqrt();
            let diff: Vec<f32> = g16[r.clone()].iter().zip(&g32[r.clone()]).map(|(a, b)| a - b).collect();
            let rel = norm(&diff) / norm(&g32[r.clone()]).max(1e-12);
            assert!(
                rel < 2e-2,
                "{tag}: gradient of {} differs by {rel:.4} (relative L2)",
                t.name
            );
        }
    }
}
