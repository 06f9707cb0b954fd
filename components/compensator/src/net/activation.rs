//! The LSTM's sigmoid and tanh in f32 arithmetic, without libm, so a gate column vectorises.
//!
//! An LSTM trial activates 4·H = 512 gates and H = 128 cell states. Through libm (`expf`,
//! `tanhf` → `expm1f`) that is 640 scalar calls, ≈ 6 µs of the accurate controller's step
//! (`perf` on `bench compensate --config configs/controller-accurate.toml --scenario fine`:
//! 26 % of the step in `__expm1f`, `__tanhf` and `__expf`). Here the same functions are
//! branch-free expressions of IEEE adds, multiplies and bit operations, which the compiler
//! turns into 8-lane AVX2 code:
//!
//! - `exp`: Cody–Waite reduction x = n·ln 2 + r, |r| ≤ ln 2 / 2, Cephes' degree-6 polynomial
//!   for e^r, 2^n through the exponent bits (Moshier, *Methods and Programs for Mathematical
//!   Functions*, 1989: `expf`);
//! - `sigmoid(x) = 1 / (1 + e^−x)`;
//! - `tanh`: Cephes `tanhf`: an odd polynomial for |x| < 0.625, `1 − 2 / (e^2|x| + 1)` beyond.
//!
//! Accuracy (tested against f64 over a dense sweep): exp within 2 ulp, sigmoid and tanh within
//! 2.5e-7 absolute, far below the 1e-4° the load check allows against tract. NaN propagates
//! (`f32::clamp` and the comparisons keep it), as libm's would, so a NaN input still reaches
//! the compensator's non-finite checks. No FMA is used, and the AVX2 build and the portable
//! build compute the same bits.

/// e^x for f32: within 2 ulp on [−87, 88]; clamped outside (e^88 ≈ 1.65e38, e^−87 ≈ 1.6e-38);
/// NaN in, NaN out.
#[inline(always)]
pub(crate) fn exp(x: f32) -> f32 {
    // `clamp` keeps NaN.
    let x = x.clamp(-87.0, 88.0);
    // n = round(x·log2 e) to nearest by the 1.5·2^23 shifter: |x·log2 e| < 128 ≪ 2^22.
    const SHIFTER: f32 = 12_582_912.0;
    let n = (x * std::f32::consts::LOG2_E + SHIFTER) - SHIFTER;
    // r = x − n·ln 2 in two parts (Cody–Waite): n·0.693359375 is exact.
    let r = x - n * 0.693_359_4;
    let r = r - n * -2.121_944_4e-4;
    let mut p = 1.987_569_2e-4f32;
    p = p * r + 1.398_199_9e-3;
    p = p * r + 8.333_452e-3;
    p = p * r + 4.166_579_6e-2;
    p = p * r + 1.666_666_5e-1;
    p = p * r + 5.0e-1;
    let y = p * (r * r) + r + 1.0;
    // 2^n: n + 127 into the exponent field (n ∈ [−126, 127] after the clamp). The shifter
    // puts the integer n + 127 in the low mantissa bits of (n + 127 + 1.5·2^23).
    let biased = (n + (127.0 + SHIFTER)).to_bits().wrapping_sub(SHIFTER.to_bits());
    y * f32::from_bits(biased.wrapping_shl(23))
}

/// 1 / (1 + e^−x).
#[inline(always)]
pub(crate) fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + exp(-x))
}

/// tanh for f32 (Cephes `tanhf`): both branches are computed and one is selected, so a lane
/// costs the same whatever its value.
#[inline(always)]
pub(crate) fn tanh(x: f32) -> f32 {
    let a = x.abs();
    let big = (1.0 - 2.0 / (exp(2.0 * a) + 1.0)).copysign(x);
    let z = x * x;
    let mut p = -5.704_988_7e-3f32;
    p = p * z + 2.063_909e-2;
    p = p * z - 5.373_971_6e-2;
    p = p * z + 1.333_144_2e-1;
    p = p * z - 3.333_328e-1;
    let small = p * z * x + x;
    if a >= 0.625 {
        big
    } else {
        small
    }
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
        *v = sigmoid(*v);
    }
    for v in th.iter_mut() {
        *v = tanh(*v);
    }
}

#[inline(always)]
fn out_gate_body(h: &mut [f32], o: &[f32], c: &[f32]) {
    for ((h, &o), &c) in h.iter_mut().zip(o).zip(c) {
        *h = o * tanh(c);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every 1/4096 on [−100, 100] plus the edges.
    fn sweep() -> impl Iterator<Item = f32> {
        (-409_600..=409_600)
            .map(|i| i as f32 / 4096.0)
            .chain([0.0, -0.0, 1e-30, -1e-30, 1e-8, -1e-8, 0.625, -0.625, 88.0, -87.0])
    }

    #[test]
    fn exp_is_within_two_ulp_where_it_is_a_normal_float() {
        for x in sweep().filter(|x| (-87.0..=88.0).contains(x)) {
            let want = (x as f64).exp();
            let got = exp(x) as f64;
            let ulp = (want as f32).abs() * f32::EPSILON;
            assert!((got - want).abs() <= 2.0 * ulp as f64, "exp({x}) = {got}, want {want}");
        }
        assert_eq!(exp(0.0), 1.0);
        assert_eq!(exp(1000.0), exp(88.0));
        assert!(exp(-1000.0) > 0.0 && exp(-1000.0) < 1e-37);
    }

    #[test]
    fn sigmoid_and_tanh_are_within_2_5e_7() {
        let mut worst = (0.0f64, 0.0f64);
        for x in sweep() {
            let xd = x as f64;
            let s = 1.0 / (1.0 + (-xd).exp());
            worst.0 = worst.0.max((sigmoid(x) as f64 - s).abs());
            worst.1 = worst.1.max((tanh(x) as f64 - xd.tanh()).abs());
            if x != 0.0 {
                assert_eq!(tanh(-x).to_bits(), (-tanh(x)).to_bits(), "tanh odd at {x}");
            }
        }
        assert!(worst.0 <= 2.5e-7 && worst.1 <= 2.5e-7, "worst |error| {worst:?}");
        assert_eq!(tanh(0.0), 0.0);
        assert_eq!(sigmoid(0.0), 0.5);
        assert_eq!(tanh(1e4), 1.0);
        assert_eq!(sigmoid(1e4), 1.0);
    }

    #[test]
    fn nan_propagates() {
        assert!(exp(f32::NAN).is_nan());
        assert!(sigmoid(f32::NAN).is_nan());
        assert!(tanh(f32::NAN).is_nan());
        let mut s = [0.3, f32::NAN, -2.0];
        let mut t = [f32::NAN, 0.1];
        gates(&mut s, &mut t);
        assert!(!s[0].is_nan() && s[1].is_nan() && t[0].is_nan() && !t[1].is_nan());
    }

    #[test]
    fn vector_and_scalar_builds_agree_bit_for_bit() {
        let xs: Vec<f32> = sweep().step_by(37).collect();
        let (mut sig, mut th) = (xs.clone(), xs.clone());
        gates(&mut sig, &mut th);
        let mut h = vec![0.0; xs.len()];
        let o: Vec<f32> = xs.iter().map(|x| (x * 0.01).sin()).collect();
        out_gate(&mut h, &o, &xs);
        for (i, &x) in xs.iter().enumerate() {
            assert_eq!(sig[i].to_bits(), sigmoid(x).to_bits(), "sigmoid({x})");
            assert_eq!(th[i].to_bits(), tanh(x).to_bits(), "tanh({x})");
            assert_eq!(h[i].to_bits(), (o[i] * tanh(x)).to_bits(), "o·tanh({x})");
        }
    }
}
