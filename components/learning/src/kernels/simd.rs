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

// The activations are shared with the real-time evaluators, which must run a model with the
// functions it was trained with.
pub use bowden_fastmath::{exp_f32, sigmoid_f32, tanh_f32};
