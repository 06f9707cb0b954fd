//! The LSTM's gate activations, 8 lanes at a time, with the functions training uses.
//!
//! An LSTM column activates 4·H = 512 gates and H = 128 cell states. Through libm (`expf`,
//! `tanhf` → `expm1f`) that was 640 scalar calls, ≈ 6 µs of the accurate controller's step
//! (`perf` on `bench compensate --config configs/controller-accurate.toml --scenario fine`:
//! 26 % of the step in `__expm1f`, `__tanhf` and `__expf`). [`bowden_fastmath`] has the same
//! functions as branch-free f32 expressions, the ones `bowden-learning` trains with, so a loop
//! over a gate column compiles to AVX2 code here and the model runs with exactly the
//! activations it was trained with. They differ from libm by at most 3e-7 (tested there); the
//! load check against tract still holds the evaluator to 1e-4°. The AVX2 and the portable
//! builds compute the same bits (no FMA).

use bowden_fastmath::{sigmoid_f32, tanh_f32};

/// tanh of one value (the LSTM tangents use it for tanh(c)).
#[inline(always)]
pub(crate) fn tanh(x: f32) -> f32 {
    tanh_f32(x)
}

/// LSTM gate activations in place: sigmoid on `sig` (gates i, o, f), tanh on `th` (c̃).
pub(crate) fn gates(sig: &mut [f32], th: &mut [f32]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2 (checked just above).
        unsafe { gates_avx2(sig, th) };
        return;
    }
    gates_body(sig, th)
}

/// `h = o ∘ tanh(c)`, lane by lane.
pub(crate) fn out_gate(h: &mut [f32], o: &[f32], c: &[f32]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2 (checked just above).
        unsafe { out_gate_avx2(h, o, c) };
        return;
    }
    out_gate_body(h, o, c)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn gates_avx2(sig: &mut [f32], th: &mut [f32]) {
    gates_body(sig, th)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn out_gate_avx2(h: &mut [f32], o: &[f32], c: &[f32]) {
    out_gate_body(h, o, c)
}

#[inline(always)]
fn gates_body(sig: &mut [f32], th: &mut [f32]) {
    for v in sig.iter_mut() {
        *v = sigmoid_f32(*v);
    }
    for v in th.iter_mut() {
        *v = tanh_f32(*v);
    }
}

#[inline(always)]
fn out_gate_body(h: &mut [f32], o: &[f32], c: &[f32]) {
    for ((h, &o), &c) in h.iter_mut().zip(o).zip(c) {
        *h = o * tanh_f32(c);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nan_propagates_through_a_gate_column() {
        let mut s = [0.3, f32::NAN, -2.0];
        let mut t = [f32::NAN, 0.1];
        gates(&mut s, &mut t);
        assert!(!s[0].is_nan() && s[1].is_nan() && t[0].is_nan() && !t[1].is_nan());
        let mut h = [0.0; 2];
        out_gate(&mut h, &[0.5, 0.5], &[f32::NAN, 1.0]);
        assert!(h[0].is_nan() && !h[1].is_nan());
    }

    /// The vectorised columns against the scalar functions (compiled without AVX2 here).
    #[test]
    fn vector_and_scalar_builds_agree_bit_for_bit() {
        let xs: Vec<f32> = (-40_000..=40_000).map(|i| i as f32 / 997.0).collect();
        let (mut sig, mut th) = (xs.clone(), xs.clone());
        gates(&mut sig, &mut th);
        let o: Vec<f32> = xs.iter().map(|x| (x * 0.01).sin()).collect();
        let mut h = vec![0.0; xs.len()];
        out_gate(&mut h, &o, &xs);
        for (i, &x) in xs.iter().enumerate() {
            assert_eq!(sig[i].to_bits(), sigmoid_f32(x).to_bits(), "sigmoid({x})");
            assert_eq!(th[i].to_bits(), tanh_f32(x).to_bits(), "tanh({x})");
            assert_eq!(h[i].to_bits(), (o[i] * tanh_f32(x)).to_bits(), "o·tanh({x})");
        }
    }
}
