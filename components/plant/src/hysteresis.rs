//! The tendon-sheath friction model of one cable: capstan dead band and stretch, and the
//! play operators that carry the cable's memory.
//!
//! A cable of compliance c = L/(E·A) runs through a sheath of total wrap angle φ with Coulomb
//! friction μ and holds a distal tension T. Let x = μφ. Quasi-statically, while the proximal end
//! is being pulled, friction opposes the motion and the tension rises exponentially toward the
//! drive (capstan, T·e^{x}); integrated over the length the stretch is c·T·(e^{x} − 1)/x. While it
//! is being released, friction reverses and the stretch is c·T·(1 − e^{−x})/x. At the same distal
//! position the proximal end therefore sits at two places 2·c·T·(cosh x − 1)/x apart, and after
//! a reversal it must travel that whole width before the distal end moves again: a dead band of
//! half-width
//!
//!   h = c·T·(cosh x − 1)/x          (≈ c·T·x/2 for small x),
//!
//! centred on the mean stretch c·T·sinh(x)/x. The band grows with the wrap angle (curvature of
//! the routing) and with the tension, as tendon-sheath experiments show (Kaneko; Do et al.).
//! Friction is not uniform along a real sheath, so the distal end starts to follow gradually: the
//! memory is a generalised Prandtl–Ishlinskii operator, the mean of several play operators whose
//! thresholds spread around h and scale with it as tension and wrap change.

/// Dead-band half-width (mm) of a cable: compliance c (mm/N), distal tension T (N), capstan
/// exponent x = μφ (≥ 0). Exact limit at x = 0 (no friction, no dead band).
#[inline]
pub fn capstan_half_width_mm(compliance_mm_per_n: f64, tension_n: f64, x: f64) -> f64 {
    // (cosh x − 1)/x, by its series near 0 where the quotient cancels.
    let f = if x.abs() < 1e-3 {
        let x2 = x * x;
        x * (0.5 + x2 / 24.0)
    } else {
        (x.cosh() - 1.0) / x
    };
    compliance_mm_per_n * tension_n * f
}

/// Mean stretch (mm) of a cable between its pulled and released states: c·T·sinh(x)/x.
#[inline]
pub fn capstan_mean_stretch_mm(compliance_mm_per_n: f64, tension_n: f64, x: f64) -> f64 {
    let g = if x.abs() < 1e-3 {
        let x2 = x * x;
        1.0 + x2 / 6.0 + x2 * x2 / 120.0
    } else {
        x.sinh() / x
    };
    compliance_mm_per_n * tension_n * g
}

/// One play (backlash) operator: the output stays where it was unless the input drags it,
/// staying within `half_width_mm` of the input. Never panics (a negative width counts as 0).
#[inline]
pub fn play(previous_mm: f64, input_mm: f64, half_width_mm: f64) -> f64 {
    let r = half_width_mm.max(0.0);
    previous_mm.max(input_mm - r).min(input_mm + r)
}

/// Threshold multipliers of `n` plays spread uniformly over [1 − s, 1 + s] (mean exactly 1).
pub fn threshold_scales(n: usize, spread: f64, out: &mut [f64]) {
    for (k, v) in out.iter_mut().enumerate().take(n) {
        *v = 1.0 + spread * (2.0 * (k as f64 + 0.5) / n as f64 - 1.0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dead_band_matches_the_pulled_and_released_stretch() {
        let (c, t) = (0.2, 5.0);
        for x in [1e-4, 0.01, 0.3, 1.0, 2.5] {
            let pulled = c * t * (f64::exp(x) - 1.0) / x;
            let released = c * t * (1.0 - f64::exp(-x)) / x;
            let h = capstan_half_width_mm(c, t, x);
            let m = capstan_mean_stretch_mm(c, t, x);
            assert!((2.0 * h - (pulled - released)).abs() < 1e-9, "x {x}");
            assert!((m - 0.5 * (pulled + released)).abs() < 1e-9, "x {x}");
        }
        assert_eq!(capstan_half_width_mm(c, t, 0.0), 0.0);
        assert!((capstan_mean_stretch_mm(c, t, 0.0) - c * t).abs() < 1e-15);
    }

    #[test]
    fn dead_band_grows_with_wrap_and_tension() {
        let c = 0.2;
        assert!(capstan_half_width_mm(c, 5.0, 0.6) > capstan_half_width_mm(c, 5.0, 0.3));
        assert!(capstan_half_width_mm(c, 8.0, 0.3) > capstan_half_width_mm(c, 5.0, 0.3));
    }

    #[test]
    fn play_holds_inside_and_follows_outside_the_band() {
        assert_eq!(play(0.0, 0.5, 1.0), 0.0);
        assert_eq!(play(0.0, 1.5, 1.0), 0.5);
        assert_eq!(play(0.0, -1.5, 1.0), -0.5);
        assert_eq!(play(0.3, 0.0, -1.0), 0.0);
    }

    #[test]
    fn thresholds_have_unit_mean() {
        let mut s = [0.0; 6];
        threshold_scales(6, 0.8, &mut s);
        assert!((s.iter().sum::<f64>() / 6.0 - 1.0).abs() < 1e-12);
        assert!(s[0] > 0.0 && s[5] < 2.0);
        threshold_scales(1, 0.8, &mut s);
        assert_eq!(s[0], 1.0);
    }
}
