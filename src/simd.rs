//! The CPU features of the SIMD copies of the hot loops, detected in one place, and the one
//! way to choose between a portable and an AVX2 copy of a loop (`dispatch!`).
//!
//! Every SIMD loop of the crate is plain Rust compiled twice, for the baseline target and with
//! `#[target_feature]`; Rust never contracts a·b + c into an FMA on its own, so both copies
//! perform the same IEEE operations in the same order and give the same bits: outputs do not
//! depend on the CPU. Users: the codec's decoders (`codec::simd`, `dispatch!`), the batch
//! lookups of tables and the structured tabulation (`fast`, AVX2 + FMA copies chosen per
//! kernel so that tests can force the portable one).

/// True when the CPU has AVX2 (the codec's decoder loops and the 3-D stencil loops of
/// tables need nothing else).
#[inline]
pub fn avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Defines `$name` that runs `$body` (an `#[inline(always)]` fn) through its AVX2 copy when
/// the CPU has AVX2, else the portable copy. Same bits either way (module doc; FMA is not
/// enabled).
macro_rules! dispatch {
    ($(#[$m:meta])* $vis:vis fn $name:ident / $avx:ident => $body:ident ( $($a:ident : $t:ty),* $(,)? ) $(-> $r:ty)?) => {
        $(#[$m])*
        $vis fn $name($($a: $t),*) $(-> $r)? {
            #[cfg(target_arch = "x86_64")]
            if $crate::simd::avx2() {
                // SAFETY: only called when the CPU reports AVX2.
                return unsafe { $avx($($a),*) };
            }
            $body($($a),*)
        }
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx2")]
        unsafe fn $avx($($a: $t),*) $(-> $r)? {
            $body($($a),*)
        }
    };
}
pub(crate) use dispatch;

/// True when the AVX2 + FMA copies of the structured tabulation and batch lookup loops can
/// run on this CPU.
pub fn avx2_fma() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}
