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
}
