//! ln, log1p and asinh for the log-space interpolation of tables (`table::LogSpace`): every
//! neighbour of every lookup passes through asinh, and libm's (hypot, then log1p through a
//! dispatch) was a quarter of a `pack` on a log-space grid. Inlined here, in plain f64
//! arithmetic (no FMA, no lookup table), so the results are the same on every machine.

use std::f64::consts::{LN_2, SQRT_2};

/// ln 2 with its low 32 mantissa bits cleared, so that k·LN2_HI is exact for |k| < 2²⁰, and
/// the rest of the f64 ln 2 (Cody–Waite splitting).
const LN2_HI: f64 = f64::from_bits(LN_2.to_bits() & !0xFFFF_FFFF);
const LN2_LO: f64 = LN_2 - LN2_HI;

/// 2 atanh(s) = 2(s + s³/3 + s⁵/5 + …) for |s| ≤ 0.172: ten terms leave a truncation
/// error below 0.172²¹/10.5, 10⁻¹⁷ relative.
#[inline(always)]
fn two_atanh(s: f64) -> f64 {
    // Estrin's scheme in z = s², w = z²: shorter dependency chains than Horner's.
    let z = s * s;
    let w = z * z;
    let w2 = w * w;
    let p01 = 1.0 + z * (1.0 / 3.0);
    let p23 = 1.0 / 5.0 + z * (1.0 / 7.0);
    let p45 = 1.0 / 9.0 + z * (1.0 / 11.0);
    let p67 = 1.0 / 13.0 + z * (1.0 / 15.0);
    let p89 = 1.0 / 17.0 + z * (1.0 / 19.0);
    let series = (p01 + w * p23) + w2 * ((p45 + w * p67) + w2 * p89);
    2.0 * s * series
}

/// ln(a) for a finite a ≥ 1 (an error of a few ulps): a = 2ᵏ·m with m in [√½, √2), and
/// ln m = 2 atanh((m − 1)/(m + 1)), the argument at most 0.172.
#[inline(always)]
fn ln_at_least_1(a: f64) -> f64 {
    const MANTISSA: u64 = (1 << 52) - 1;
    let bits = a.to_bits();
    let mut k = ((bits >> 52) as i64 - 1023) as f64;
    let mut m = f64::from_bits((bits & MANTISSA) | 1.0f64.to_bits());
    if m > SQRT_2 {
        m *= 0.5;
        k += 1.0;
    }
    // m − 1 is exact (Sterbenz) for m in [√½, √2).
    let ln_m = two_atanh((m - 1.0) / (m + 1.0));
    k * LN2_HI + (ln_m + k * LN2_LO)
}

/// ln(1 + t) for a finite t ≥ 0. Below 10⁻⁸ its series; below √2 − 1 it is 2 atanh(t/(2 + t)), from t itself
/// (1 + t would round away t's low bits). Above, 1 + t is rounded to a, and the rounding's
/// error e (exact, by Fast2Sum with the larger term first) is put back to first order:
/// ln(a + e) ≈ ln a + e/a.
#[inline(always)]
pub fn ln_1p_nonneg(t: f64) -> f64 {
    if t < 1e-8 {
        // t − t²/2 + t³/3, within 10⁻²⁴ relative; and no t/2 rounded to a subnormal.
        return t * (1.0 - t * (0.5 - t * (1.0 / 3.0)));
    }
    if t < SQRT_2 - 1.0 {
        return two_atanh(t / (2.0 + t));
    }
    let a = 1.0 + t;
    let e = if t > 1.0 {
        1.0 - (a - t)
    } else {
        t - (a - 1.0)
    };
    ln_at_least_1(a) + e / a
}

/// asinh(x), odd. For |x| < ½: log1p(|x| + x²/(1 + √(1 + x²))) (no cancellation for small
/// |x|); up to 2⁵⁰⁰: ln(|x| + √(1 + x²)) (1 + x² cannot overflow); above, ln 2|x|, which asinh equals to far below an ulp there.
/// NaN gives NaN and ±∞ gives ±∞, as libm's.
#[inline(always)]
pub fn asinh(x: f64) -> f64 {
    const LARGE: f64 = 3.273_390_607_896_142e150; // 2⁵⁰⁰
    let ax = x.abs();
    if !ax.is_finite() {
        return x;
    }
    let y = if ax > LARGE {
        ln_at_least_1(ax) + LN_2
    } else if ax >= 0.5 {
        // x + √(1 + x²) ≥ 1.6 has no cancellation: one ln, no log1p.
        ln_at_least_1(ax + (1.0 + ax * ax).sqrt())
    } else {
        let x2 = ax * ax;
        ln_1p_nonneg(ax + x2 / (1.0 + (1.0 + x2).sqrt()))
    };
    y.copysign(x)
}

/// [`asinh`] of every value of `xs`, in place (the portable copy of
/// [`asinh_in_place_avx2`]).
pub fn asinh_in_place(xs: &mut [f64]) {
    for x in xs {
        *x = asinh(*x);
    }
}

/// [`asinh`] of every value of `xs`, in place, four at a time in AVX2 lanes: the bits of one
/// [`asinh`] per value. Lanes whose |x| lies in [½, 2⁵⁰⁰] (the log-space lookups' usual
/// arguments, a value over half the space's scale) take [`asinh`]'s middle branch, the same
/// IEEE operations in the same order (no FMA: Rust never contracts, and the intrinsics are
/// separate multiplies and adds; the exponent split by integer shifts and masks, the
/// exponent turned into an f64 exactly); a group of four with any other lane is done one
/// value at a time by [`asinh`].
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
pub unsafe fn asinh_in_place_avx2(xs: &mut [f64]) {
    use std::arch::x86_64::*;
    const LARGE: f64 = 3.273_390_607_896_142e150; // 2⁵⁰⁰, as in `asinh`
    const MANTISSA: i64 = (1 << 52) - 1;
    let sign = _mm256_set1_pd(-0.0);
    let one = _mm256_set1_pd(1.0);
    let half = _mm256_set1_pd(0.5);
    let large = _mm256_set1_pd(LARGE);
    // 2⁵² as bits: or-ing a small integer into its mantissa and subtracting 2⁵² converts it.
    let two52_bits = _mm256_set1_epi64x(0x4330_0000_0000_0000);
    let two52 = _mm256_set1_pd(4_503_599_627_370_496.0);
    let bias = _mm256_set1_pd(1023.0);
    let mantissa = _mm256_set1_epi64x(MANTISSA);
    let one_bits = _mm256_set1_epi64x(1.0f64.to_bits() as i64);
    let sqrt2 = _mm256_set1_pd(SQRT_2);
    let c = |v: f64| _mm256_set1_pd(v);
    let mut chunks = xs.chunks_exact_mut(4);
    for q in &mut chunks {
        // SAFETY: `q` holds 4 f64.
        let x = unsafe { _mm256_loadu_pd(q.as_ptr()) };
        let ax = _mm256_andnot_pd(sign, x);
        let inside = _mm256_and_pd(
            _mm256_cmp_pd::<_CMP_GE_OQ>(ax, half),
            _mm256_cmp_pd::<_CMP_LE_OQ>(ax, large),
        );
        if _mm256_movemask_pd(inside) != 0b1111 {
            for v in q.iter_mut() {
                *v = asinh(*v);
            }
            continue;
        }
        // a = |x| + √(1 + x²), then ln a as `ln_at_least_1`.
        let a = _mm256_add_pd(
            ax,
            _mm256_sqrt_pd(_mm256_add_pd(one, _mm256_mul_pd(ax, ax))),
        );
        let bits = _mm256_castpd_si256(a);
        let e = _mm256_srli_epi64::<52>(bits);
        let e = _mm256_sub_pd(_mm256_castsi256_pd(_mm256_or_si256(e, two52_bits)), two52);
        let k = _mm256_sub_pd(e, bias);
        let m = _mm256_castsi256_pd(_mm256_or_si256(_mm256_and_si256(bits, mantissa), one_bits));
        let above = _mm256_cmp_pd::<_CMP_GT_OQ>(m, sqrt2);
        let m = _mm256_blendv_pd(m, _mm256_mul_pd(m, half), above);
        let k = _mm256_blendv_pd(k, _mm256_add_pd(k, one), above);
        let s = _mm256_div_pd(_mm256_sub_pd(m, one), _mm256_add_pd(m, one));
        // `two_atanh`.
        let z = _mm256_mul_pd(s, s);
        let w = _mm256_mul_pd(z, z);
        let w2 = _mm256_mul_pd(w, w);
        let p = |a: f64, b: f64| _mm256_add_pd(c(a), _mm256_mul_pd(z, c(b)));
        let p01 = _mm256_add_pd(one, _mm256_mul_pd(z, c(1.0 / 3.0)));
        let p23 = p(1.0 / 5.0, 1.0 / 7.0);
        let p45 = p(1.0 / 9.0, 1.0 / 11.0);
        let p67 = p(1.0 / 13.0, 1.0 / 15.0);
        let p89 = p(1.0 / 17.0, 1.0 / 19.0);
        let series = _mm256_add_pd(
            _mm256_add_pd(p01, _mm256_mul_pd(w, p23)),
            _mm256_mul_pd(
                w2,
                _mm256_add_pd(
                    _mm256_add_pd(p45, _mm256_mul_pd(w, p67)),
                    _mm256_mul_pd(w2, p89),
                ),
            ),
        );
        let ln_m = _mm256_mul_pd(_mm256_mul_pd(c(2.0), s), series);
        let y = _mm256_add_pd(
            _mm256_mul_pd(k, c(LN2_HI)),
            _mm256_add_pd(ln_m, _mm256_mul_pd(k, c(LN2_LO))),
        );
        // y > 0.48: copysign is x's sign bit or-ed in.
        let y = _mm256_or_pd(y, _mm256_and_pd(x, sign));
        // SAFETY: `q` holds 4 f64.
        unsafe { _mm256_storeu_pd(q.as_mut_ptr(), y) };
    }
    for v in chunks.into_remainder() {
        *v = asinh(*v);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::SplitMix64;

    /// Relative error against libm (which is within an ulp), or absolute where libm gives 0.
    fn rel(a: f64, b: f64) -> f64 {
        if b == 0.0 {
            a.abs()
        } else {
            ((a - b) / b).abs()
        }
    }

    #[test]
    fn asinh_and_log1p_match_libm_to_a_few_ulps() {
        let mut rng = SplitMix64::new(11);
        let (mut worst_asinh, mut worst_log1p): (f64, f64) = (0.0, 0.0);
        for i in 0..400_000 {
            // log-uniform magnitudes from 1e-310 (subnormal) to 1e300, both signs, plus
            // arguments next to 1 (where 1 + t rounds) and next to the m = √2 split.
            let x = match i % 4 {
                0 | 1 => 10f64.powf(-310.0 + 610.0 * rng.next_f64()),
                2 => 1.0 + (rng.next_f64() - 0.5) * 1e-6,
                _ => SQRT_2 - 1.0 + (rng.next_f64() - 0.5) * 1e-9,
            };
            let x = if i % 3 == 0 { -x } else { x };
            worst_asinh = worst_asinh.max(rel(asinh(x), x.asinh()));
            let t = x.abs();
            worst_log1p = worst_log1p.max(rel(ln_1p_nonneg(t), t.ln_1p()));
        }
        // Three ulps (2.2e-16 relative each at worst): libm is within one, and these add
        // the roundings of s = t/(2 + t) (or of 1 + t) and of the series' last products.
        assert!(
            worst_asinh < 6.7e-16,
            "asinh: max relative error {worst_asinh:e}"
        );
        assert!(
            worst_log1p < 6.7e-16,
            "log1p: max relative error {worst_log1p:e}"
        );
    }

    #[test]
    fn asinh_keeps_its_special_values_and_symmetry() {
        assert_eq!(asinh(0.0).to_bits(), 0.0f64.to_bits());
        assert_eq!(asinh(-0.0).to_bits(), (-0.0f64).to_bits());
        assert_eq!(asinh(f64::INFINITY), f64::INFINITY);
        assert_eq!(asinh(f64::NEG_INFINITY), f64::NEG_INFINITY);
        assert!(asinh(f64::NAN).is_nan());
        // libm's asinh overflows to ∞ here (x² does); ln 2x does not.
        assert!(rel(asinh(f64::MAX), f64::MAX.ln() + LN_2) < 4e-16);
        assert_eq!(asinh(f64::MIN_POSITIVE * 0.5), f64::MIN_POSITIVE * 0.5);
        for x in [1e-300, 3e-8, 0.5, 1.0, 7.25, 1e10, 1e200] {
            assert_eq!(asinh(-x), -asinh(x));
        }
    }

    /// The AVX2 copy gives [`asinh`]'s bits for every value: magnitudes from subnormal to
    /// beyond 2⁵⁰⁰, both signs, zeros, the ½ and √2 splits, infinities and NaN, mixed in
    /// groups of four and in a remainder.
    #[test]
    fn asinh_in_place_has_the_bits_of_asinh() {
        let mut rng = SplitMix64::new(23);
        let mut xs: Vec<f64> = (0..200_003)
            .map(|i| {
                let x = match i % 8 {
                    0..=3 => 10f64.powf(-2.0 + 12.0 * rng.next_f64()),
                    4 => 10f64.powf(-310.0 + 620.0 * rng.next_f64()),
                    5 => 0.5 + (rng.next_f64() - 0.5) * 1e-9,
                    6 => [0.0, f64::INFINITY, f64::NAN, 3.2e150, 3.3e150, f64::MAX][i / 8 % 6],
                    _ => 0.2071 + 0.001 * rng.next_f64(),
                };
                if rng.next_f64() < 0.3 { -x } else { x }
            })
            .collect();
        // Runs of in-range lanes too (the vector path), not only mixed groups.
        xs.extend((0..4000).map(|i| 0.5 + i as f64 * 0.37));
        let want: Vec<u64> = xs.iter().map(|&x| asinh(x).to_bits()).collect();
        let mut portable = xs.clone();
        asinh_in_place(&mut portable);
        assert!(
            portable
                .iter()
                .map(|v| v.to_bits())
                .eq(want.iter().copied())
        );
        #[cfg(target_arch = "x86_64")]
        if std::is_x86_feature_detected!("avx2") {
            let mut v = xs.clone();
            // SAFETY: the CPU has AVX2.
            unsafe { asinh_in_place_avx2(&mut v) };
            for (i, (a, b)) in v.iter().zip(&want).enumerate() {
                assert_eq!(
                    a.to_bits(),
                    *b,
                    "x = {:e}: {a:e} vs {:e}",
                    xs[i],
                    f64::from_bits(*b)
                );
            }
        }
    }
}
