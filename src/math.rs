//! The numerics toolbox (f64 throughout), after pbrt-v4's `util/math.h`.

pub mod atan;
pub mod log;
pub mod sobol;

pub const PI: f64 = std::f64::consts::PI;
pub const FRAC_1_PI: f64 = std::f64::consts::FRAC_1_PI;
pub const FRAC_PI_2: f64 = std::f64::consts::FRAC_PI_2;

#[inline]
pub fn sqr(x: f64) -> f64 {
    x * x
}

/// sqrt that tolerates tiny negative arguments produced by rounding.
/// Debug builds assert the argument was not meaningfully negative.
#[inline]
pub fn safe_sqrt(x: f64) -> f64 {
    debug_assert!(x >= -1e-9, "safe_sqrt of {x}");
    x.max(0.0).sqrt()
}

/// acos that clamps its argument to [-1, 1] (rounding can push a dot product past 1).
#[inline]
pub fn safe_acos(x: f64) -> f64 {
    x.clamp(-1.0, 1.0).acos()
}

/// a*b - c*d with one rounding error (Kahan's algorithm via fused multiply-add).
#[inline]
pub fn difference_of_products(a: f64, b: f64, c: f64, d: f64) -> f64 {
    let cd = c * d;
    let err = (-c).mul_add(d, cd);
    let dop = a.mul_add(b, -cd);
    dop + err
}

/// Error function (libm's port of FreeBSD msun, < 1 ulp).
#[inline]
pub fn erf(x: f64) -> f64 {
    libm::erf(x)
}

/// Complementary error function, accurate for large x where 1 - erf(x) would cancel.
#[inline]
pub fn erfc(x: f64) -> f64 {
    libm::erfc(x)
}

/// x^n with 0^0 = 1 (the spec's convention) and without overflow/underflow surprises
/// for huge exponents: evaluated as exp(n ln x) when n is large.
#[inline]
pub fn pow_0_0_is_1(x: f64, n: f64) -> f64 {
    if n == 0.0 {
        1.0
    } else if x <= 0.0 {
        0.0
    } else {
        (n * x.ln()).exp()
    }
}

/// SplitMix64: a tiny, well-studied, seedable generator (Steele et al. 2014). Used for
/// every sample set so that reports are reproducible from the printed seed.
#[derive(Clone, Debug)]
pub struct SplitMix64 {
    state: u64,
}

impl SplitMix64 {
    pub fn new(seed: u64) -> Self {
        Self { state: seed }
    }

    #[inline]
    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1) with 53 random bits.
    #[inline]
    pub fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn difference_of_products_is_exact_where_naive_cancels() {
        // (1 + 2^-30)^2 - 1 * (1 + 2^-29): naive form loses the 2^-60 term entirely.
        let a = 1.0 + 2f64.powi(-30);
        let got = difference_of_products(a, a, 1.0, 1.0 + 2f64.powi(-29));
        assert_eq!(got, 2f64.powi(-60));
    }

    #[test]
    fn pow_convention() {
        assert_eq!(pow_0_0_is_1(0.0, 0.0), 1.0);
        assert_eq!(pow_0_0_is_1(0.0, 3.0), 0.0);
        assert!((pow_0_0_is_1(0.5, 2.0) - 0.25).abs() < 1e-15);
        assert_eq!(pow_0_0_is_1(0.999, 1e6), (1e6 * 0.999f64.ln()).exp());
    }

    #[test]
    fn erfc_large_argument_does_not_cancel() {
        // erfc(10) = 2.088487583762545e-45 (A&S 7.1); 1 - erf(10) would be 0.
        let v = erfc(10.0);
        assert!((v / 2.088_487_583_762_545e-45 - 1.0).abs() < 1e-13, "{v}");
    }

    #[test]
    fn splitmix_is_deterministic_and_in_range() {
        let mut a = SplitMix64::new(7);
        let mut b = SplitMix64::new(7);
        for _ in 0..1000 {
            let x = a.next_f64();
            assert_eq!(x, b.next_f64());
            assert!((0.0..1.0).contains(&x));
        }
    }
}
