//! atan for the vectorized loops of the structured tabulation (`tabulate::structured`) and
//! the batch lookups of tables (`table::lookup`): branch-free, so that the loops calling it
//! vectorize (`crate::simd` for the SIMD copies).

/// π/2 and π/4 split in two parts (Cody–Waite), for argument reduction in [`atan_ratio`].
const FRAC_PI_2_HI: f64 = std::f64::consts::FRAC_PI_2;
const FRAC_PI_4_HI: f64 = std::f64::consts::FRAC_PI_4;
/// The part of π/4 below f64 precision (Cephes `MOREBITS` halved twice: π/2 − FRAC_PI_2 is
/// 6.123e-17).
#[allow(clippy::excessive_precision)]
const FRAC_PI_4_LO: f64 = 3.061_616_997_868_382_9e-17;
#[allow(clippy::excessive_precision)]
const FRAC_PI_2_LO: f64 = 6.123_233_995_736_765_9e-17;

/// atan(y/x) for 0 ≤ y ≤ x (an angle in [0, π/4]); 0 when both are 0. Branch-free (selects
/// only) so that loops calling it vectorize. Cephes `atan` (Moshier 1989): for y/x > 0.66 the
/// argument is reduced by atan(u) = π/4 + atan((u − 1)/(u + 1)), then a degree 4/5 rational
/// in u² gives ~1 ulp. Taking the ratio here saves a division: the reduced argument is
/// (y − x)/(y + x), one quotient instead of y/x followed by (u − 1)/(u + 1).
#[inline(always)]
#[allow(clippy::excessive_precision)]
pub fn atan_ratio(y: f64, x: f64) -> f64 {
    const P: [f64; 5] = [
        -8.750_608_600_031_904_122_785e-1,
        -1.615_753_718_733_365_076_637e1,
        -7.500_855_792_314_704_667_340e1,
        -1.228_866_684_490_136_173_410e2,
        -6.485_021_904_942_025_371_773e1,
    ];
    const Q: [f64; 5] = [
        2.485_846_490_142_306_297_962e1,
        1.650_270_098_316_988_542_046e2,
        4.328_810_604_912_902_668_951e2,
        4.853_903_996_359_136_964_868e2,
        1.945_506_571_482_613_964_425e2,
    ];
    let reduce = y > 0.66 * x;
    let (num, den) = if reduce { (y - x, y + x) } else { (y, x) };
    // Both zero: the angle is undefined; 0 like libm's atan2(0, 0) (num is 0 then).
    let den = if den > 0.0 { den } else { 1.0 };
    let xr = num / den;
    let z = xr * xr;
    let p = (((P[0] * z + P[1]) * z + P[2]) * z + P[3]) * z + P[4];
    let q = ((((z + Q[0]) * z + Q[1]) * z + Q[2]) * z + Q[3]) * z + Q[4];
    let r = xr * (z * p / q) + xr;
    if reduce {
        FRAC_PI_4_HI + (r + FRAC_PI_4_LO)
    } else {
        r
    }
}

/// atan2(y, x) for y ≥ 0, x ≥ 0 (an angle in [0, π/2]); 0 when both are 0. Branch-free.
#[inline(always)]
pub fn atan2_first_quadrant(y: f64, x: f64) -> f64 {
    let swap = y > x;
    let (lo, hi) = if swap { (x, y) } else { (y, x) };
    let a = atan_ratio(lo, hi);
    if swap {
        FRAC_PI_2_HI - (a - FRAC_PI_2_LO)
    } else {
        a
    }
}

/// atan2(y, x) over the full circle, in [−π, π], branch-free. Signed zeros are not
/// distinguished (atan2(−0, −1) gives π, libm gives −π): callers fold φ anyway.
#[inline(always)]
pub fn atan2_full(y: f64, x: f64) -> f64 {
    let a = atan2_first_quadrant(y.abs(), x.abs());
    let a = if x < 0.0 { std::f64::consts::PI - a } else { a };
    if y < 0.0 { -a } else { a }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::SplitMix64;

    #[test]
    fn fast_atan_matches_libm_to_a_few_ulps() {
        let mut rng = SplitMix64::new(7);
        let mut worst: f64 = 0.0;
        for i in 0..200_000 {
            // Uniform in [0, 1], plus tiny arguments and the reduction threshold.
            let x = match i % 4 {
                0 => rng.next_f64(),
                1 => rng.next_f64() * 1e-8,
                2 => 0.66 + (rng.next_f64() - 0.5) * 1e-6,
                _ => 1.0 - rng.next_f64() * 1e-6,
            };
            // The same ratio at another scale (the reduction compares y with 0.66·x).
            let s = 0.5 + 4.0 * rng.next_f64();
            let (a, b) = (atan_ratio(x, 1.0), x.atan());
            let a2 = atan_ratio(x * s, s);
            if b != 0.0 {
                worst = worst.max(((a - b) / b).abs()).max(((a2 - b) / b).abs());
            } else {
                assert_eq!(a, 0.0);
            }
        }
        assert!(worst < 1e-15, "max relative error {worst:e}");
        let mut worst2: f64 = 0.0;
        for _ in 0..200_000 {
            let y = rng.next_f64() * 2.0 - 1.0;
            let x = rng.next_f64() * 2.0 - 1.0;
            let (a, b) = (atan2_full(y, x), y.atan2(x));
            worst2 = worst2.max((a - b).abs());
            let (a, b) = (
                atan2_first_quadrant(y.abs(), x.abs()),
                y.abs().atan2(x.abs()),
            );
            worst2 = worst2.max((a - b).abs());
        }
        assert!(worst2 < 1e-15, "max absolute error {worst2:e}");
        assert_eq!(atan2_first_quadrant(0.0, 0.0), 0.0);
        assert_eq!(atan_ratio(0.0, 0.0), 0.0);
        assert_eq!(atan2_first_quadrant(1.0, 0.0), std::f64::consts::FRAC_PI_2);
    }
}
