//! The portable (non-AVX-512) kernels: same loss and gradients as candle (its stored results,
//! `reference.rs`), and finite differences agree with the fused gradient independently of
//! candle. The switch is process-wide: the other tests of this binary then run the portable
//! kernels too, which they are held to with the same tolerances.

use bowden_learning::arch::ModelSpec;
use bowden_learning::kernels::{simd, Net};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn setup(spec: ModelSpec, b: usize, seed: u64) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let params = spec.init_params(seed);
    let x = (0..b * spec.seq_len * spec.joints)
        .map(|_| rng.random_range(-1.5f32..1.5))
        .collect();
    let y = (0..b * spec.joints).map(|_| rng.random_range(-1.0f32..1.0)).collect();
    (params, x, y)
}

fn fused_grad(spec: ModelSpec, params: &[f32], x: &[f32], y: &[f32], b: usize) -> (f64, Vec<f32>) {
    let net = Net::new(spec);
    let prep = net.prepared(params);
    let mut ws = net.workspace(b);
    let mut grad = vec![0.0; net.param_count()];
    let sse = net.forward_backward(
        params,
        &prep,
        x,
        y,
        b,
        2.0 / (b * spec.joints) as f32,
        &mut ws,
        &mut grad,
    );
    (sse / (b * spec.joints) as f64, grad)
}

#[test]
fn portable_kernels_match_candle_and_finite_differences() {
    simd::force_portable(true);
    assert!(!simd::has_avx512());
    for name in ["portable_tcn", "portable_lstm", "portable_tcn_lstm", "portable_fnn"] {
        let case = crate::reference::case(name);
        let (spec, b) = (case.spec, case.b);
        let (params, x, y) = setup(spec, b, case.seed);
        let (loss, grad) = fused_grad(spec, &params, &x, &y, b);
        let reference = crate::reference::load(&case);
        let (want_loss, want) = (reference.loss, reference.grad);
        assert!(((loss - want_loss) / want_loss).abs() < 1e-5, "{}", spec.arch);
        let gmax = want.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        let err = grad
            .iter()
            .zip(&want)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(
            err < 1e-4 * gmax,
            "{}: portable gradient differs from candle by {err}",
            spec.arch
        );

        // Central differences on the first element of every tensor (f64 loss from the
        // fused forward pass); h chosen for f32 and away from ReLU kinks.
        let layout = spec.layout();
        for t in &layout.tensors {
            let i = t.range().start;
            let h = 3e-3f32;
            let mut p = params.clone();
            p[i] += h;
            let lp = fused_grad(spec, &p, &x, &y, b).0;
            p[i] -= 2.0 * h;
            let lm = fused_grad(spec, &p, &x, &y, b).0;
            let fd = (lp - lm) / (2.0 * h as f64);
            let tol = 2e-3 * gmax as f64 + 1e-4;
            assert!(
                (fd - grad[i] as f64).abs() < tol,
                "{}: {} [0]: finite difference {fd} vs gradient {}",
                spec.arch,
                t.name,
                grad[i]
            );
        }
    }
}
