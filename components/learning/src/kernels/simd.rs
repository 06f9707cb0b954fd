//! CPU feature dispatch and vectorisable elementwise math.
//!
//! The hot loops are written once as plain Rust over slices; [`simd_fn!`] compiles each of
//! them twice, once for the baseline target and once with AVX-512 enabled, and picks at run
//! time. Elementwise code does no reassociation, so both builds give the same bits; only the
//! GEMM's FMA rounding differs between the two paths.

use std::sync::atomic::{AtomicU8, Ordering};

static SIMD: AtomicU8 = AtomicU8::new(0); // 0 = unknown, 1 = portable, 2 = avx512

/// True when the AVX-512 kernels are used (detected once; [`force_portable`] overrides).
#[inline]
pub fn has_avx512() -> bool {
    match SIMD.load(Ordering::Relaxed) {
        2 => true,
        1 => false,
        _ => {
            let yes = detect();
            SIMD.store(if yes { 2 } else { 1 }, Ordering::Relaxed);
            yes
        }
    }
}

#[cfg(target_arch = "x86_64")]
fn detect() -> bool {
    std::arch::is_x86_feature_detected!("avx512f")
        && std::arch::is_x86_feature_detected!("avx512vl")
        && std::arch::is_x86_feature_detected!("fma")
        && std::arch::is_x86_feature_detected!("avx2")
}

#[cfg(not(target_arch = "x86_64"))]
fn detect() -> bool {
    false
}

/// Uses the portable kernels from now on in this process (tests of the fallback path, and
/// bit-reproducibility across machines with different CPUs).
pub fn force_portable(yes: bool) {
    SIMD.store(if yes { 1 } else { 0 }, Ordering::Relaxed);
}

/// Defines `fn name(args) -> ret { body }` compiled for the baseline and for AVX-512, with
/// run-time dispatch.
macro_rules! simd_fn {
    ($(#[$m:meta])* $vis:vis fn $name:ident($($a:ident : $t:ty),* $(,)?) $(-> $r:ty)? $body:block) => {
        $(#[$m])*
        #[allow(clippy::too_many_arguments)]
        $vis fn $name($($a: $t),*) $(-> $r)? {
            #[inline(always)]
            #[allow(clippy::too_many_arguments)]
            fn body($($a: $t),*) $(-> $r)? $body
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx512f,avx512vl,avx2,fma")]
                #[allow(clippy::too_many_arguments)]
                unsafe fn fast($($a: $t),*) $(-> $r)? { body($($a),*) }
                if $crate::kernels::simd::has_avx512() {
                    // SAFETY: the CPU has the features `fast` was compiled for.
                    return unsafe { fast($($a),*) };
                }
            }
            body($($a),*)
        }
    };
}
pub(crate) use simd_fn;

const LOG2E: f32 = std::f32::consts::LOG2_E;
const LN2_HI: f32 = 0.693_359_4;
const LN2_LO: f32 = -2.121_944_4e-4;
/// 1.5·2²³: adding and subtracting it rounds to the nearest integer in f32.
const ROUND_MAGIC: f32 = 12_582_912.0;

/// e^x in f32 (Cephes' polynomial, ≈ 1 ulp over the clamped range), branch-free so a loop
/// of it vectorises.
#[inline(always)]
pub fn exp_f32(x: f32) -> f32 {
    let x = x.clamp(-87.0, 88.0);
    let shifted = x * LOG2E + ROUND_MAGIC;
    let n = shifted - ROUND_MAGIC;
    let r = x - n * LN2_HI - n * LN2_LO;
    let mut p = 1.987_569_1e-4f32;
    p = p * r + 1.398_199_9e-3;
    p = p * r + 8.333_452e-3;
    p = p * r + 4.166_579_6e-2;
    p = p * r + 1.666_666_5e-1;
    p = p * r + 0.5;
    let e = p * r * r + r + 1.0;
    // 2ⁿ from the integer n sitting in the low mantissa bits of `shifted` (its bits are
    // 0x4B40_0000 + n): integer ops only, so the loop stays vectorised (a float → int `as`
    // cast saturates and is scalarised).
    let scale = f32::from_bits(shifted.to_bits().wrapping_sub(0x4B40_0000 - 127) << 23);
    e * scale
}

#[inline(always)]
pub fn sigmoid_f32(x: f32) -> f32 {
    1.0 / (1.0 + exp_f32(-x))
}

#[inline(always)]
pub fn tanh_f32(x: f32) -> f32 {
    // 2σ(2x) − 1; absolute error ~1e-7 near 0, which is what matters here.
    2.0 / (1.0 + exp_f32(-2.0 * x)) - 1.0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_sigmoid_tanh_match_std() {
        let mut worst_exp = 0.0f64;
        let mut worst_abs = 0.0f64;
        let mut x = -30.0f32;
        while x < 30.0 {
            let e = exp_f32(x) as f64;
            let r = (x as f64).exp();
            worst_exp = worst_exp.max(((e - r) / r).abs());
            worst_abs = worst_abs.max((sigmoid_f32(x) as f64 - 1.0 / (1.0 + (-(x as f64)).exp())).abs());
            worst_abs = worst_abs.max((tanh_f32(x) as f64 - (x as f64).tanh()).abs());
            x += 0.0137;
        }
        assert!(worst_exp < 3e-7, "exp rel err {worst_exp}");
        assert!(worst_abs < 3e-7, "sigmoid/tanh abs err {worst_abs}");
        assert!(sigmoid_f32(-200.0) >= 0.0 && sigmoid_f32(-200.0) < 1e-37);
        assert!(sigmoid_f32(200.0) == 1.0 && tanh_f32(200.0) == 1.0 && tanh_f32(-200.0) == -1.0);
    }
}
