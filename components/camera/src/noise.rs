//! Sensor-noise primitives: a Gaussian quantile table (one lookup per normal sample, so a
//! whole 640×480 frame of noise costs far less than a frame period) and sRGB transfer
//! tables.

/// Number of entries of the Gaussian quantile table (12 random bits per sample).
pub const GAUSS_BITS: u32 = 12;
pub const GAUSS_LEN: usize = 1 << GAUSS_BITS;

/// Inverse of the standard normal CDF (Acklam's rational approximation, |rel. error| < 1.2e-9).
pub fn inverse_normal_cdf(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969683028665376e+01,
        2.209460984245205e+02,
        -2.759285104469687e+02,
        1.383_577_518_672_69e2,
        -3.066479806614716e+01,
        2.506628277459239e+00,
    ];
    const B: [f64; 5] = [
        -5.447609879822406e+01,
        1.615858368580409e+02,
        -1.556989798598866e+02,
        6.680131188771972e+01,
        -1.328068155288572e+01,
    ];
    const C: [f64; 6] = [
        -7.784894002430293e-03,
        -3.223964580411365e-01,
        -2.400758277161838e+00,
        -2.549732539343734e+00,
        4.374664141464968e+00,
        2.938163982698783e+00,
    ];
    const D: [f64; 4] = [
        7.784695709041462e-03,
        3.224671290700398e-01,
        2.445134137142996e+00,
        3.754408661907416e+00,
    ];
    const P_LOW: f64 = 0.02425;
    if p <= 0.0 {
        return f64::NEG_INFINITY;
    }
    if p >= 1.0 {
        return f64::INFINITY;
    }
    if p < P_LOW {
        let q = (-2.0 * p.ln()).sqrt();
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    } else if p <= 1.0 - P_LOW {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    } else {
        -inverse_normal_cdf(1.0 - p)
    }
}

/// Standard-normal quantiles at the centres of `GAUSS_LEN` equal-probability bins: indexing
/// it with uniform random bits draws N(0, 1) quantised to 4096 levels (tails cut at ±3.49σ,
/// which also bounds the noise deterministically).
pub fn gauss_table() -> Vec<f32> {
    (0..GAUSS_LEN)
        .map(|i| inverse_normal_cdf((i as f64 + 0.5) / GAUSS_LEN as f64) as f32)
        .collect()
}

/// Largest |value| in [`gauss_table`]: the noise bound in standard deviations.
pub fn gauss_table_max_sigma() -> f64 {
    inverse_normal_cdf(1.0 - 0.5 / GAUSS_LEN as f64)
}

/// Colour noise as a table: entry `value·256 + k` is 8-bit `value` plus σ(value)·g_k,
/// rounded and clamped, where g_k are the 256 standard-normal quantiles (rescaled to unit
/// variance) and σ² = read² + gain·value (read and shot noise, DN).
pub fn color_noise_table(read_noise_dn: f64, shot_noise_gain_dn: f64) -> Vec<u8> {
    let g: Vec<f64> = (0..256).map(|k| inverse_normal_cdf((k as f64 + 0.5) / 256.0)).collect();
    let sd = (g.iter().map(|x| x * x).sum::<f64>() / 256.0).sqrt();
    let mut t = Vec::with_capacity(256 * 256);
    for v in 0..256 {
        let sigma = (read_noise_dn * read_noise_dn + shot_noise_gain_dn * v as f64).sqrt();
        for gk in &g {
            t.push((v as f64 + sigma * gk / sd).round().clamp(0.0, 255.0) as u8);
        }
    }
    t
}

/// sRGB 8-bit value → linear [0, 1].
pub fn srgb_to_linear(v: u8) -> f32 {
    let c = v as f64 / 255.0;
    let l = if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    };
    l as f32
}

/// Entries of the linear → sRGB table.
pub const LIN_TO_SRGB_LEN: usize = 4096;

/// Linear [0, 1] (quantised to 4096 levels) → sRGB 8-bit.
pub fn linear_to_srgb_table() -> Vec<u8> {
    (0..LIN_TO_SRGB_LEN)
        .map(|i| {
            let l = i as f64 / (LIN_TO_SRGB_LEN - 1) as f64;
            let c = if l <= 0.0031308 {
                12.92 * l
            } else {
                1.055 * l.powf(1.0 / 2.4) - 0.055
            };
            (c * 255.0 + 0.5).clamp(0.0, 255.0) as u8
        })
        .collect()
}

/// A 64-bit finaliser (SplitMix64): decorrelates integer coordinates for procedural
/// textures (scene content, not sensor noise).
#[inline]
pub fn mix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantile_table_is_standard_normal() {
        let t = gauss_table();
        let n = t.len() as f64;
        let mean = t.iter().map(|&x| x as f64).sum::<f64>() / n;
        let var = t.iter().map(|&x| (x as f64 - mean).powi(2)).sum::<f64>() / n;
        assert!(mean.abs() < 1e-6, "mean {mean}");
        // Binning the distribution loses a little variance in the tails.
        assert!((var.sqrt() - 1.0).abs() < 0.01, "sd {}", var.sqrt());
        assert!(t.windows(2).all(|w| w[0] < w[1]));
        assert!((inverse_normal_cdf(0.975) - 1.959964).abs() < 1e-5);
        assert!((inverse_normal_cdf(0.001) + 3.090232).abs() < 1e-5);
    }

    #[test]
    fn srgb_round_trip() {
        let t = linear_to_srgb_table();
        for v in 0..=255u8 {
            let l = srgb_to_linear(v);
            let back = t[(l * (LIN_TO_SRGB_LEN - 1) as f32 + 0.5) as usize];
            // 4096 linear levels are coarse only in the darkest sRGB codes.
            assert!((back as i32 - v as i32).abs() <= 2, "{v} -> {l} -> {back}");
        }
    }
}
