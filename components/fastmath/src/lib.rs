//! The f32 `exp`, `sigmoid` and `tanh` that training (`bowden-learning`'s LSTM kernels) and
//! the real-time evaluators (`bowden-compensator`'s incremental LSTM) share, so a model is run
//! with the very activation functions it was trained with.
//!
//! Each is a branch-free expression of IEEE adds, multiplies, divisions and bit operations: a
//! loop over a slice of them vectorises (8 or 16 lanes), where libm's `expf`/`tanhf` are one
//! scalar call per element (≈ 10 ns each; an LSTM column activates 640 values). No FMA is
//! used, so every CPU and every vector width gives the same bits, and the results do not
//! depend on the C library's version.
//!
//! - [`exp_f32`]: Cody–Waite reduction x = n·ln 2 + r and Cephes' degree-6 polynomial for e^r
//!   (Moshier, *Methods and Programs for Mathematical Functions*, 1989: `expf`), 2ⁿ through
//!   the exponent bits; ≈ 1 ulp (3e-7 relative) on the clamped range [−87, 88].
//! - [`sigmoid_f32`] = 1 / (1 + e^−x); [`tanh_f32`] = 2σ(2x) − 1: within 3e-7 absolute.
//!
//! NaN in gives NaN out (`f32::clamp` keeps it), so a NaN input still reaches the callers'
//! non-finite checks.
//!
//! Both sides also share [`AVec`], the buffer type of their weights and workspaces: its data
//! start on a 64-byte cache line, so no vector load of a weight row straddles two lines
//! whatever the allocator returned ([`aligned`]).

pub mod aligned;
pub use aligned::AVec;

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

    #[test]
    fn exp_is_exact_at_zero_and_clamped_outside_its_range() {
        assert_eq!(exp_f32(0.0), 1.0);
        assert_eq!(sigmoid_f32(0.0), 0.5);
        assert_eq!(tanh_f32(0.0), 0.0);
        assert_eq!(exp_f32(1000.0), exp_f32(88.0));
        assert!(exp_f32(88.0).is_finite() && exp_f32(-1000.0) > 0.0);
    }

    #[test]
    fn nan_propagates() {
        assert!(exp_f32(f32::NAN).is_nan());
        assert!(sigmoid_f32(f32::NAN).is_nan());
        assert!(tanh_f32(f32::NAN).is_nan());
    }
}
