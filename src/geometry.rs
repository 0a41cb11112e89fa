//! Directions, the local shading frame (z = normal, x = tangent) and the
//! half/difference parameterization of Rusinkiewicz (1998).

use crate::math::{FRAC_PI_2, sqr};
use std::ops::{Add, Mul, Neg, Sub};

/// A 3-vector in f64. Directions in this crate are unit vectors in the local frame
/// (z = surface normal) pointing away from the surface.
#[derive(Clone, Copy, Debug, PartialEq, Default, serde::Serialize, serde::Deserialize)]
pub struct Vec3 {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

impl Vec3 {
    pub const Z: Vec3 = Vec3 {
        x: 0.0,
        y: 0.0,
        z: 1.0,
    };

    #[inline]
    pub const fn new(x: f64, y: f64, z: f64) -> Self {
        Self { x, y, z }
    }
    #[inline]
    pub fn dot(self, o: Vec3) -> f64 {
        self.x * o.x + self.y * o.y + self.z * o.z
    }
    #[inline]
    pub fn cross(self, o: Vec3) -> Vec3 {
        Vec3::new(
            self.y * o.z - self.z * o.y,
            self.z * o.x - self.x * o.z,
            self.x * o.y - self.y * o.x,
        )
    }
    #[inline]
    pub fn length_squared(self) -> f64 {
        self.dot(self)
    }
    #[inline]
    pub fn length(self) -> f64 {
        self.length_squared().sqrt()
    }
    /// The unit vector along `self`, or `None` when it is zero or has a NaN or infinite
    /// component. Components as large as 1e200 or as small as 1e-200 are fine: their squared
    /// length overflows or underflows, so such vectors are scaled by their largest component
    /// first (an `eval` input of `1e200,0,1e200` was reported as "zero length").
    #[inline]
    pub fn try_normalize(self) -> Option<Vec3> {
        let l2 = self.length_squared();
        if l2.is_finite() && l2 >= f64::MIN_POSITIVE {
            return Some(self * (1.0 / l2.sqrt()));
        }
        if !self.is_finite() {
            return None;
        }
        let s = self.x.abs().max(self.y.abs()).max(self.z.abs());
        if s == 0.0 {
            return None;
        }
        // Division, not multiplication by 1/s: 1/s overflows for subnormal s.
        let v = Vec3::new(self.x / s, self.y / s, self.z / s);
        Some(v * (1.0 / v.length()))
    }
    #[inline]
    pub fn is_finite(self) -> bool {
        self.x.is_finite() && self.y.is_finite() && self.z.is_finite()
    }
    /// sin²θ measured from the normal, as x² + y² (no cancellation near the normal).
    #[inline]
    pub fn sin2_theta(self) -> f64 {
        sqr(self.x) + sqr(self.y)
    }
    /// tan²θ = (x² + y²)/z², the spec's cancellation-free form.
    #[inline]
    pub fn tan2_theta(self) -> f64 {
        self.sin2_theta() / sqr(self.z)
    }
    /// Polar angle from the normal by atan2 (exact near 0 and π/2, unlike acos).
    #[inline]
    pub fn theta(self) -> f64 {
        self.sin2_theta().sqrt().atan2(self.z)
    }
    /// Azimuth in (-π, π]; 0 when undefined (on the normal).
    #[inline]
    pub fn phi(self) -> f64 {
        self.y.atan2(self.x)
    }
    /// Mirror direction about the normal: (-x, -y, z).
    #[inline]
    pub fn mirror(self) -> Vec3 {
        Vec3::new(-self.x, -self.y, self.z)
    }
    /// Unit direction from spherical angles. cos(π/2) is returned as exactly 0 so that a grid
    /// sample placed on the horizon is recognised as such (f64 cos gives 6.1e-17 there).
    #[inline]
    pub fn from_spherical(theta: f64, phi: f64) -> Vec3 {
        let (st, ct) = theta.sin_cos();
        let ct = if theta == FRAC_PI_2 { 0.0 } else { ct };
        let (sp, cp) = phi.sin_cos();
        Vec3::new(st * cp, st * sp, ct)
    }
    /// Rotation about z by angle `a` (counter-clockwise).
    #[inline]
    pub fn rotate_z(self, a: f64) -> Vec3 {
        let (s, c) = a.sin_cos();
        Vec3::new(c * self.x - s * self.y, s * self.x + c * self.y, self.z)
    }
    /// Rotation about y by angle `a` (right-handed: z towards x).
    #[inline]
    pub fn rotate_y(self, a: f64) -> Vec3 {
        let (s, c) = a.sin_cos();
        Vec3::new(c * self.x + s * self.z, self.y, -s * self.x + c * self.z)
    }
    #[inline]
    pub fn to_array(self) -> [f64; 3] {
        [self.x, self.y, self.z]
    }
}

impl Add for Vec3 {
    type Output = Vec3;
    #[inline]
    fn add(self, o: Vec3) -> Vec3 {
        Vec3::new(self.x + o.x, self.y + o.y, self.z + o.z)
    }
}
impl Sub for Vec3 {
    type Output = Vec3;
    #[inline]
    fn sub(self, o: Vec3) -> Vec3 {
        Vec3::new(self.x - o.x, self.y - o.y, self.z - o.z)
    }
}
impl Mul<f64> for Vec3 {
    type Output = Vec3;
    #[inline]
    fn mul(self, s: f64) -> Vec3 {
        Vec3::new(self.x * s, self.y * s, self.z * s)
    }
}
impl Neg for Vec3 {
    type Output = Vec3;
    #[inline]
    fn neg(self) -> Vec3 {
        Vec3::new(-self.x, -self.y, -self.z)
    }
}

/// The half vector of two unit directions and the cosine of the difference angle,
/// (h, cos θd) with h = (wi + wo)/|wi + wo| and cos θd = wi·h = wo·h = |wi + wo|/2
/// (Rusinkiewicz 1998); `None` when wi = −wo (no half vector).
///
/// cos θd is taken from the length of wi + wo, not as wi·h: that is the same number for
/// (wi, wo) and (wo, wi), whereas wi·h and wo·h differ by rounding — for nearly opposite
/// pairs 1e-8 above the horizon (cos θd ≈ 1e-8) by a third, and Ashikhmin–Shirley gave
/// 4.4e14 one way and 3.0e14 the other (tests/hard_cases.rs). It is clamped to 1: rounding
/// can give 1 + 2^-52, and Schlick's (1 − c)⁵ then went negative (f = −1e-78 for f0 = 0).
#[inline]
pub fn half_vector(wi: Vec3, wo: Vec3) -> Option<(Vec3, f64)> {
    let s = wi + wo;
    let h = s.try_normalize()?;
    Some((h, (0.5 * s.dot(h)).min(1.0)))
}

/// 1 − cos θd of two unit directions without cancellation: |wi − wo|²/(4(1 + cos θd)),
/// symmetric in wi and wo and never negative (1 − c computed directly loses every digit near
/// retro-reflection, and goes negative when c rounds above 1).
#[inline]
pub fn one_minus_cos_theta_d(wi: Vec3, wo: Vec3, cos_theta_d: f64) -> f64 {
    (wi - wo).length_squared() / (4.0 * (1.0 + cos_theta_d))
}

/// Rusinkiewicz's half/difference angles of a direction pair (radians).
/// φh, φd in (-π, π].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HalfDiff {
    pub theta_h: f64,
    pub phi_h: f64,
    pub theta_d: f64,
    pub phi_d: f64,
}

impl HalfDiff {
    /// Angles of the pair (wi, wo), or `None` when wi + wo has zero length (wi = −wo:
    /// the half vector is undefined). The difference vector is wi expressed in the frame
    /// whose z is the half vector (rotate by −φh about z, then −θh about y), and every angle
    /// is taken by atan2 so that θh ≈ 0 and θd ≈ 90° stay exact.
    pub fn from_dirs(wi: Vec3, wo: Vec3) -> Option<HalfDiff> {
        let h = (wi + wo).try_normalize()?;
        let theta_h = h.theta();
        let phi_h = h.phi();
        let d = wi.rotate_z(-phi_h).rotate_y(-theta_h);
        Some(HalfDiff {
            theta_h,
            phi_h,
            theta_d: d.theta(),
            phi_d: d.phi(),
        })
    }

    /// The direction pair (wi, wo). wo is the difference vector mirrored about the half
    /// vector in the half frame, (−dx, −dy, dz), rotated back: an exact reflection without
    /// the cancellation of 2(wi·h)h − wi.
    pub fn to_dirs(self) -> (Vec3, Vec3) {
        let d = Vec3::from_spherical(self.theta_d, self.phi_d);
        let back = |v: Vec3| v.rotate_y(self.theta_h).rotate_z(self.phi_h);
        (back(d), back(d.mirror()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::{PI, SplitMix64};

    fn random_dir(rng: &mut SplitMix64) -> Vec3 {
        let z = rng.next_f64();
        let phi = 2.0 * PI * rng.next_f64();
        let r = (1.0 - z * z).max(0.0).sqrt();
        Vec3::new(r * phi.cos(), r * phi.sin(), z)
    }

    #[test]
    fn half_diff_round_trip() {
        let mut rng = SplitMix64::new(1);
        for _ in 0..10_000 {
            let wi = random_dir(&mut rng);
            let wo = random_dir(&mut rng);
            let hd = HalfDiff::from_dirs(wi, wo).unwrap();
            let (a, b) = hd.to_dirs();
            assert!((a - wi).length() < 1e-13, "{wi:?} {a:?}");
            assert!((b - wo).length() < 1e-13, "{wo:?} {b:?}");
        }
    }

    #[test]
    fn tiny_half_angle_is_exact() {
        // wi and wo mirror images tilted by 1e-9 rad: θh = 1e-9 / 2 must come out to full
        // relative precision (acos(h.z) would return 0).
        let t = 1e-9;
        let wi = Vec3::from_spherical(0.5 + t, 0.0);
        let wo = Vec3::from_spherical(0.5 - t, PI);
        let hd = HalfDiff::from_dirs(wi, wo).unwrap();
        assert!((hd.theta_h / t - 1.0).abs() < 1e-6, "{}", hd.theta_h);
        assert!((hd.theta_d - 0.5).abs() < 1e-12);
    }

    #[test]
    fn opposite_directions_have_no_half_vector() {
        let wi = Vec3::new(0.6, 0.0, 0.8);
        assert!(HalfDiff::from_dirs(wi, -wi).is_none());
    }

    #[test]
    fn horizon_is_exactly_zero() {
        assert_eq!(Vec3::from_spherical(FRAC_PI_2, 0.3).z, 0.0);
    }
}
