//! Physical properties of any [`Brdf`] (analytic model, table, measured file): positivity,
//! reciprocity, isotropy and the directional albedo a(θi) = ∫ f(wi, wo) cos θo dωo.
//!
//! # Directional-albedo quadrature
//!
//! The integral is taken over the half vector h (Walter et al. 2007, Eq. 13–14):
//! wo = 2(wi·h)h − wi and dωo = 4 (wi·h) dωh. Every lobe centred on the mirror direction
//! (Phong, microfacet, Ward, the specular peak of a measured material) is centred on h = z
//! in these coordinates, for every incidence, so one grid resolves them all.
//!
//! 1. Rotate the frame by −φi so that wi = (sin θi, 0, cos θi).
//! 2. For each azimuth φh, the directions h that send wo above the horizon are exactly
//!    θh ≤ θh,max(φh) = (π/2 + atan2(sin θi cos φh, cos θi))/2 (from
//!    wo.z = sin θi cos φh sin 2θh + cos θi cos 2θh). Integrating θh over [0, θh,max(φh)]
//!    removes the horizon kink from the integrand; wi·h > 0 holds on the whole domain.
//! 3. s = θh/θh,max ∈ [0, 1] is cut into panels graded geometrically (ratio 3, from 6.3e-7
//!    to 1/9) and then at most 0.1 wide up to 1 (ending 0.9, 0.95, 1), each with
//!    Gauss–Legendre nodes: a peak of any width between 1e-6 rad and the whole domain meets
//!    panels of its own size, algebraic tails (GGX) are integrated panel by panel, and kinks
//!    anywhere (interpolated tables) cost at most a 0.1-wide panel's worth of error.
//! 4. φh uses the trapezoidal rule at φh = k · 2π/N, which converges geometrically for the
//!    smooth periodic integrand of step 2 and nests (N/2 ⊂ N).
//! 5. Error estimate and adaptivity: see [`albedo_estimate`]. Cost: 54,912 evaluations per
//!    incidence (FINE 42,240 + COARSE 12,672) when the azimuthal estimate is below 1e-5, up
//!    to 350,592 for strongly anisotropic sources (N = 1536).
//!
//! Measured accuracy and cost: `docs/props.md` and the tests below.

use crate::brdf::Brdf;
use crate::geometry::Vec3;
use crate::math::{FRAC_PI_2, PI, SplitMix64};
use rayon::prelude::*;

/// One quadrature rule over the half vector: the graded θh panels of
/// `nodes_per_panel` Gauss–Legendre nodes each, times `n_phi` trapezoidal azimuths.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct HalfVectorRule {
    pub nodes_per_panel: usize,
    pub n_phi: usize,
}

impl HalfVectorRule {
    /// The rule used only for the first error estimate.
    pub const COARSE: HalfVectorRule = HalfVectorRule {
        nodes_per_panel: 6,
        n_phi: 96,
    };
    /// The first rule whose value is reported.
    pub const FINE: HalfVectorRule = HalfVectorRule {
        nodes_per_panel: 10,
        n_phi: 192,
    };
    /// The largest azimuth count of the adaptive refinement (8 × FINE).
    pub const MAX_N_PHI: usize = 1536;

    /// BRDF evaluations this rule takes per incidence direction.
    pub fn evaluations(&self) -> usize {
        (theta_h_breaks().len() - 1) * self.nodes_per_panel * self.n_phi
    }
}

/// The error estimate at which [`albedo_estimate`] stops refining (a tenth of the
/// documented accuracy [`ALBEDO_TOLERANCE`]).
pub const ALBEDO_TARGET_ERROR: f64 = 1e-5;

/// Panel boundaries in s = θh/θh,max: 0, 3^-13, ..., 3^-2, then 0.2, 0.3, ..., 0.9, 0.95, 1.
fn theta_h_breaks() -> Vec<f64> {
    // Ratio 3 keeps the nearest complex singularity of a Lorentzian-like peak (GGX) far
    // enough from each panel for 10 nodes to reach ~1e-8 relative error per panel.
    const RATIO: f64 = 3.0;
    // 3^-13 = 6.3e-7: peaks narrower than ~1e-6 rad of θh (α < 1e-6) fall inside one panel.
    const LEVELS: i32 = 13;
    let mut b = vec![0.0];
    b.extend((2..=LEVELS).rev().map(|k| RATIO.powi(-k)));
    // From 1/9 on, panels at most 0.1 wide: a source with kinks anywhere (an interpolated
    // table) then loses at most ~(0.1 θh,max)² × its slope jump per kink, and the end is
    // graded towards s = 1 (the horizon of wo), where sources that grow like 1/cos θo (the
    // original Ward model) leave an integrable endpoint singularity.
    b.extend([0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 1.0]);
    b
}

/// Gauss–Legendre nodes and weights on [−1, 1] (Newton iteration on P_n; Press et al.,
/// Numerical Recipes §4.6).
pub(crate) fn gauss_legendre(n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut x = vec![0.0; n];
    let mut w = vec![0.0; n];
    for i in 0..n.div_ceil(2) {
        // Tricomi's initial guess for the i-th root.
        let mut z = (PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
        let mut dp = 0.0;
        for _ in 0..100 {
            let (mut p0, mut p1) = (1.0, z);
            for k in 2..=n {
                let p2 = ((2 * k - 1) as f64 * z * p1 - (k - 1) as f64 * p0) / k as f64;
                p0 = p1;
                p1 = p2;
            }
            let (pn, pn1) = if n == 1 { (z, 1.0) } else { (p1, p0) };
            dp = n as f64 * (z * pn - pn1) / (z * z - 1.0);
            let dz = pn / dp;
            z -= dz;
            if dz.abs() < 1e-16 {
                break;
            }
        }
        x[i] = -z;
        x[n - 1 - i] = z;
        w[i] = 2.0 / ((1.0 - z * z) * dp * dp);
        w[n - 1 - i] = w[i];
    }
    (x, w)
}

/// Accumulates `weight · f` into `sum`, skipping non-finite values (the contract forbids
/// them; a faulty source is reported by [`props`] instead of poisoning every albedo).
#[inline]
fn accumulate(sum: &mut [f64], f: &[f64], weight: f64) {
    for (s, v) in sum.iter_mut().zip(f) {
        if v.is_finite() {
            *s += weight * v;
        }
    }
}

/// The half-vector integrand of one incidence direction (steps 1–3 of the module docs),
/// integrated over θh one azimuth row at a time.
struct HalfVectorRows<'a> {
    brdf: &'a dyn Brdf,
    /// wi in the frame rotated by −φi: (sin θi, 0, cos θi).
    wi_local: Vec3,
    wi_world: Vec3,
    phi_i: f64,
    breaks: Vec<f64>,
    gauss_x: Vec<f64>,
    gauss_w: Vec<f64>,
}

impl<'a> HalfVectorRows<'a> {
    /// `None` when wi is below the horizon or not a direction (the albedo is then 0).
    fn new(brdf: &'a dyn Brdf, wi: Vec3, nodes_per_panel: usize) -> Option<Self> {
        // Below (or on) the horizon the source is 0 by the one-sided convention.
        if !wi.is_finite() || wi.z <= 0.0 {
            return None;
        }
        let wi = wi.try_normalize()?;
        // Step 1: local frame with wi in the xz-plane.
        let phi_i = wi.phi();
        let wi_local = Vec3::new(wi.sin2_theta().sqrt(), 0.0, wi.z);
        let (gauss_x, gauss_w) = gauss_legendre(nodes_per_panel.max(1));
        Some(HalfVectorRows {
            brdf,
            wi_local,
            wi_world: wi_local.rotate_z(phi_i),
            phi_i,
            breaks: theta_h_breaks(),
            gauss_x,
            gauss_w,
        })
    }

    /// ∫ f cos θo · 4 (wi·h) sin θh dθh over [0, θh,max(φh)] at one azimuth φh.
    fn row(&self, phi_h: f64) -> Vec<f64> {
        let nc = self.brdf.channels().len();
        let mut sum = vec![0.0; nc];
        let (sin_phi_h, cos_phi_h) = phi_h.sin_cos();
        let (sin_theta_i, cos_theta_i) = (self.wi_local.x, self.wi_local.z);
        // Step 2: the largest θh keeping wo above the horizon.
        let theta_h_max = 0.5 * (FRAC_PI_2 + (sin_theta_i * cos_phi_h).atan2(cos_theta_i));
        // The row's pairs and weights first, then one batched evaluation (a table looks
        // them up several times faster than pair by pair), summed in node order.
        let mut pairs = Vec::with_capacity(self.evaluations_per_row());
        let mut weights = Vec::with_capacity(self.evaluations_per_row());
        for pair in self.breaks.windows(2) {
            let (s0, s1) = (pair[0] * theta_h_max, pair[1] * theta_h_max);
            let half = 0.5 * (s1 - s0);
            for (x, w) in self.gauss_x.iter().zip(&self.gauss_w) {
                let theta_h = s0 + half * (x + 1.0);
                let (sin_theta_h, cos_theta_h) = theta_h.sin_cos();
                let h = Vec3::new(
                    sin_theta_h * cos_phi_h,
                    sin_theta_h * sin_phi_h,
                    cos_theta_h,
                );
                let wi_dot_h = self.wi_local.dot(h);
                let wo = h * (2.0 * wi_dot_h) - self.wi_local;
                if wo.z <= 0.0 {
                    // Rounding at the domain's end: the one-sided source is 0 there.
                    continue;
                }
                pairs.push((self.wi_world, wo.rotate_z(self.phi_i)));
                // f cos θo · 4 (wi·h) sin θh dθh (Walter et al. 2007, Eq. 14).
                weights.push(w * half * wo.z * 4.0 * wi_dot_h * sin_theta_h);
            }
        }
        let mut f = vec![0.0; pairs.len() * nc];
        self.brdf.eval_pairs(&pairs, &mut f);
        for (&weight, f) in weights.iter().zip(f.chunks_exact(nc.max(1))) {
            accumulate(&mut sum, f, weight);
        }
        sum
    }

    /// Rows at φh = k · 2π/n for the given k (in parallel; order kept).
    fn rows(&self, n: usize, ks: impl IndexedParallelIterator<Item = usize>) -> Vec<Vec<f64>> {
        ks.map(|k| self.row(k as f64 * 2.0 * PI / n as f64))
            .collect()
    }

    fn evaluations_per_row(&self) -> usize {
        (self.breaks.len() - 1) * self.gauss_x.len()
    }
}

/// Step 4: the trapezoidal rule over every `stride`-th of `rows` (equally spaced azimuths
/// over 2π), summed in a fixed order so the result does not depend on the thread count.
fn trapezoid(rows: &[Vec<f64>], stride: usize, nc: usize) -> Vec<f64> {
    let mut total = vec![0.0; nc];
    let n = rows.len().div_ceil(stride);
    for r in rows.iter().step_by(stride) {
        for (t, v) in total.iter_mut().zip(r) {
            *t += v;
        }
    }
    total.iter_mut().for_each(|t| *t *= 2.0 * PI / n as f64);
    total
}

/// a(θi, φi) with one half-vector rule (steps 1–4 of the module docs).
pub fn half_vector_albedo(brdf: &dyn Brdf, wi: Vec3, rule: HalfVectorRule) -> Vec<f64> {
    let nc = brdf.channels().len();
    let Some(grid) = HalfVectorRows::new(brdf, wi, rule.nodes_per_panel) else {
        return vec![0.0; nc];
    };
    let n = rule.n_phi.max(1);
    trapezoid(&grid.rows(n, (0..n).into_par_iter()), 1, nc)
}

/// a(θi, φi) by a plain Gauss–Legendre rule in θo (`n_theta` nodes on four panels graded
/// towards the normal) times `n_phi` trapezoidal φo. Accurate for broad lobes only (it
/// misses peaks narrower than its node spacing); kept as an independent cross-check.
pub fn plain_albedo(brdf: &dyn Brdf, wi: Vec3, n_theta: usize, n_phi: usize) -> Vec<f64> {
    let nc = brdf.channels().len();
    let Some(wi) = wi.try_normalize() else {
        return vec![0.0; nc];
    };
    if wi.z <= 0.0 {
        return vec![0.0; nc];
    }
    let per_panel = n_theta.div_ceil(4).max(1);
    let (gx, gw) = gauss_legendre(per_panel);
    let breaks = [0.0, 0.125, 0.25, 0.5, 1.0].map(|s| s * FRAC_PI_2);
    let n_phi = n_phi.max(1);
    let d_phi = 2.0 * PI / n_phi as f64;
    let mut total = vec![0.0; nc];
    let mut f = vec![0.0; nc];
    for pair in breaks.windows(2) {
        let half = 0.5 * (pair[1] - pair[0]);
        for (x, w) in gx.iter().zip(&gw) {
            let theta_o = pair[0] + half * (x + 1.0);
            let (sin_theta_o, cos_theta_o) = theta_o.sin_cos();
            for k in 0..n_phi {
                let wo = Vec3::from_spherical(theta_o, (k as f64 + 0.5) * d_phi);
                brdf.eval(wi, wo, &mut f);
                accumulate(&mut total, &f, w * half * cos_theta_o * sin_theta_o * d_phi);
            }
        }
    }
    total
}

/// A directional albedo with its quadrature-error estimate, per channel.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct AlbedoEstimate {
    pub value: Vec<f64>,
    /// e_θ + e_φ per channel (see [`albedo_estimate`]): an upper estimate of the error of
    /// `value` for sources smooth on the scale of the coarse rule.
    pub error: Vec<f64>,
    /// BRDF evaluations spent.
    pub evaluations: usize,
}

/// The directional albedo at incidence (θi, φi) in radians, with its error estimate.
/// θi outside [0, π/2) gives 0 (the source is one-sided).
///
/// Step 5 of the module docs. The FINE rule's azimuths φh = k · 2π/N are nested, so the
/// same rows also give the N/2 trapezoid: e_φ = |T_N − T_N/2| estimates the azimuthal error
/// for free, and doubling N costs only the new rows. The COARSE rule (fewer θh nodes, N/2
/// azimuths) against T_N/2 gives e_θ, the error of the θh rule. While e_φ exceeds
/// [`ALBEDO_TARGET_ERROR`], N doubles (up to [`HalfVectorRule::MAX_N_PHI`]), stopping early
/// when e_φ no longer halves (the remaining error is then not azimuthal and more rows would
/// not remove it). The reported error is e_θ + e_φ.
pub fn albedo_estimate(brdf: &dyn Brdf, theta_i: f64, phi_i: f64) -> AlbedoEstimate {
    let nc = brdf.channels().len();
    let wi = Vec3::from_spherical(theta_i, phi_i);
    let (Some(fine), Some(coarse)) = (
        HalfVectorRows::new(brdf, wi, HalfVectorRule::FINE.nodes_per_panel),
        HalfVectorRows::new(brdf, wi, HalfVectorRule::COARSE.nodes_per_panel),
    ) else {
        return AlbedoEstimate {
            value: vec![0.0; nc],
            error: vec![0.0; nc],
            evaluations: 0,
        };
    };
    let diff = |a: &[f64], b: &[f64]| -> Vec<f64> {
        a.iter().zip(b).map(|(x, y)| (x - y).abs()).collect()
    };
    let worst = |e: &[f64]| e.iter().copied().fold(0.0, f64::max);

    let mut n = HalfVectorRule::FINE.n_phi;
    let mut rows = fine.rows(n, (0..n).into_par_iter());
    let mut evaluations = n * fine.evaluations_per_row();
    let coarse_n = n / 2;
    let coarse_value = trapezoid(&coarse.rows(coarse_n, (0..coarse_n).into_par_iter()), 1, nc);
    evaluations += coarse_n * coarse.evaluations_per_row();
    let e_theta = diff(&coarse_value, &trapezoid(&rows, 2, nc));

    let mut value = trapezoid(&rows, 1, nc);
    let mut e_phi = diff(&value, &trapezoid(&rows, 2, nc));
    while worst(&e_phi) > ALBEDO_TARGET_ERROR && n < HalfVectorRule::MAX_N_PHI {
        // The new rows sit halfway between the old ones.
        let odd = fine.rows(2 * n, (0..n).into_par_iter().map(|k| 2 * k + 1));
        evaluations += n * fine.evaluations_per_row();
        rows = rows
            .into_iter()
            .zip(odd)
            .flat_map(|(even, odd)| [even, odd])
            .collect();
        n *= 2;
        let finer = trapezoid(&rows, 1, nc);
        let finer_e_phi = diff(&finer, &value);
        let converging = worst(&finer_e_phi) <= 0.5 * worst(&e_phi);
        value = finer;
        e_phi = finer_e_phi;
        if !converging {
            break;
        }
    }
    let error = e_theta.iter().zip(&e_phi).map(|(a, b)| a + b).collect();
    AlbedoEstimate {
        value,
        error,
        evaluations,
    }
}

/// The directional albedo a(θi) = ∫ f(wi, wo) cos θo dωo per channel, for wi at polar angle
/// `theta_i` (radians) in the xz-plane. See the module docs for the method and its accuracy.
pub fn directional_albedo(brdf: &dyn Brdf, theta_i: f64) -> Vec<f64> {
    directional_albedo_at(brdf, theta_i, 0.0)
}

/// [`directional_albedo`] at incidence azimuth `phi_i` (radians), for anisotropic sources.
pub fn directional_albedo_at(brdf: &dyn Brdf, theta_i: f64, phi_i: f64) -> Vec<f64> {
    half_vector_albedo(
        brdf,
        Vec3::from_spherical(theta_i, phi_i),
        HalfVectorRule::FINE,
    )
}

/// The documented accuracy of the albedo quadrature on smooth sources (absolute).
pub const ALBEDO_TOLERANCE: f64 = 1e-4;

/// The incidence angles (degrees) at which albedo is reported: 0°, 5.67°, …, 85°
/// (16 angles, step 85/15°). The check module uses the same set.
pub fn albedo_angles_deg() -> [f64; 16] {
    std::array::from_fn(|i| i as f64 * 85.0 / 15.0)
}

/// The (θi, φi) pairs, in degrees, at which albedo is reported for `brdf`: the angles of
/// [`albedo_angles_deg`] at φi = 0°, and at 90° too when the source is anisotropic.
pub fn albedo_angle_pairs_deg(brdf: &dyn Brdf) -> Vec<(f64, f64)> {
    let phis: &[f64] = if brdf.is_isotropic() {
        &[0.0]
    } else {
        &[0.0, 90.0]
    };
    phis.iter()
        .flat_map(|&p| albedo_angles_deg().map(|t| (t, p)))
        .collect()
}

/// Sampling options for [`props`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct PropsOptions {
    /// Seed of the SplitMix64 stream that draws the sample pairs.
    pub seed: u64,
    /// Random direction pairs per test (fixed hard-case pairs are added to positivity).
    pub samples: usize,
}

impl Default for PropsOptions {
    fn default() -> Self {
        PropsOptions {
            seed: 1,
            samples: 65_536,
        }
    }
}

/// A direction pair where a property is worst.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct DirPair {
    #[serde(serialize_with = "json_number::many")]
    pub wi: [f64; 3],
    #[serde(serialize_with = "json_number::many")]
    pub wo: [f64; 3],
}

impl DirPair {
    fn new(wi: Vec3, wo: Vec3) -> DirPair {
        DirPair {
            wi: wi.to_array(),
            wo: wo.to_array(),
        }
    }
}

/// Values over the sample: f ≥ 0 and finite is expected.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Positivity {
    /// Pairs evaluated (random + hard cases of `spec/hard-cases.md`).
    pub pairs: usize,
    /// Smallest finite value over every pair and channel.
    pub min_value: f64,
    /// Where `min_value` occurs.
    pub min_at: DirPair,
    /// Channel values < 0.
    pub negative: usize,
    /// Channel values NaN or ±Inf (the contract allows none).
    pub nonfinite: usize,
}

/// A symmetry test: the largest relative change of f under a transformation of the pair.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Symmetry {
    /// What the source promises (`Brdf::is_reciprocal` / `Brdf::is_isotropic`).
    pub promised: bool,
    /// max |f(a) − f(b)| / max(|f(a)|, |f(b)|, floor) over pairs and channels.
    pub max_rel_diff: f64,
    /// The floor of the denominator: 1e-9 × the largest |f| over the random pairs (values
    /// below it are numerically zero for every use of a BRDF).
    pub floor: f64,
    /// Where the maximum occurs (the untransformed pair) and, for isotropy, the rotation
    /// angle in degrees.
    pub worst: DirPair,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub worst_rotation_deg: Option<f64>,
    /// `max_rel_diff <= SYMMETRY_TOLERANCE`.
    pub holds: bool,
}

/// Relative difference below which a symmetry counts as holding (rounding in f64 models
/// stays near 1e-14; interpolated tables are exactly symmetric or far from it).
pub const SYMMETRY_TOLERANCE: f64 = 1e-9;

/// Directional albedo at one incidence.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct AlbedoRow {
    pub theta_i_deg: f64,
    pub phi_i_deg: f64,
    #[serde(serialize_with = "json_number::many")]
    pub albedo: Vec<f64>,
    /// Quadrature-error estimate per channel (see [`albedo_estimate`]).
    #[serde(serialize_with = "json_number::many")]
    pub error: Vec<f64>,
    /// BRDF evaluations spent on this row.
    pub evaluations: usize,
}

/// What the albedo estimates show about energy conservation, worst first.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum EnergyVerdict {
    /// An albedo or its error estimate is NaN or infinite: the source gives non-finite
    /// values, or values whose integral overflows f64.
    NonFinite,
    /// An albedo exceeds 1 by more than max(its error estimate, [`ALBEDO_TOLERANCE`]).
    Exceeds,
    /// An albedo's error estimate is above [`ALBEDO_UNRESOLVED`] and the estimate plus its
    /// error exceeds 1: the quadrature does not resolve the source (a spike between its
    /// nodes, say), so neither conservation nor its failure is shown.
    Unresolved,
    /// Every albedo is ≤ 1 within max(its error estimate, [`ALBEDO_TOLERANCE`]).
    Conserves,
}

/// Error estimate above which an albedo that may exceed 1 counts as unresolved: a tenth of
/// the largest physical albedo (smooth sources stay below 1e-2, docs/props.md).
pub const ALBEDO_UNRESOLVED: f64 = 0.1;

/// Energy conservation: max albedo ≤ 1 within the quadrature error.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Energy {
    /// The albedo the verdict rests on: the largest one, or the first non-finite one, or
    /// the unresolved one with the largest estimate + error.
    #[serde(serialize_with = "json_number::one")]
    pub max_albedo: f64,
    pub at_theta_i_deg: f64,
    pub at_phi_i_deg: f64,
    pub channel: usize,
    /// max(error estimate at `max_albedo`, [`ALBEDO_TOLERANCE`]).
    #[serde(serialize_with = "json_number::one")]
    pub tolerance: f64,
    /// `verdict == Conserves`.
    pub conserves: bool,
    pub verdict: EnergyVerdict,
}

/// JSON has no infinities or NaN: serde_json writes them as `null`, which a reader takes for
/// a missing value. Non-finite numbers of a report are written as the strings `"inf"`,
/// `"-inf"` and `"nan"` instead (docs/props.md).
mod json_number {
    use serde::{Serialize, Serializer};

    struct Number(f64);

    impl Serialize for Number {
        fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
            let x = self.0;
            if x.is_finite() {
                s.serialize_f64(x)
            } else if x.is_nan() {
                s.serialize_str("nan")
            } else if x > 0.0 {
                s.serialize_str("inf")
            } else {
                s.serialize_str("-inf")
            }
        }
    }

    pub fn one<S: Serializer>(x: &f64, s: S) -> Result<S::Ok, S::Error> {
        Number(*x).serialize(s)
    }

    pub fn many<S: Serializer, T: AsRef<[f64]>>(xs: &T, s: S) -> Result<S::Ok, S::Error> {
        s.collect_seq(xs.as_ref().iter().map(|&x| Number(x)))
    }
}

/// The coefficient of a source's Dirac-delta (specular) part at one incidence: the energy
/// that leaves in the mirror direction, which `albedo` (an integral of pointwise values)
/// does not contain.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct SpecularRow {
    pub theta_i_deg: f64,
    pub phi_i_deg: f64,
    #[serde(serialize_with = "json_number::many")]
    pub coefficient: Vec<f64>,
}

/// Everything [`props`] measures.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct PropsReport {
    pub source: String,
    pub channels: Vec<String>,
    pub seed: u64,
    pub samples: usize,
    pub positivity: Positivity,
    pub reciprocity: Symmetry,
    pub isotropy: Symmetry,
    /// Albedo at [`albedo_angles_deg`] for φi = 0 (and φi = 90° for anisotropic sources).
    pub albedo: Vec<AlbedoRow>,
    pub energy: Energy,
    /// The properties that fail, one sentence each (empty: all pass): non-finite or negative
    /// values, a promised symmetry that does not hold, energy not conserved.
    pub failures: Vec<String>,
    /// For sources with a Dirac-delta part (HTSG's specular term): its coefficient at the
    /// albedo rows' incidences, reported apart from (and not included in) `albedo`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub specular: Option<Vec<SpecularRow>>,
    /// For HTSG (also inside a sum): the largest number of series terms any channel sums
    /// over the fixed direction set of `Htsg::series_terms_max`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub htsg_terms: Option<usize>,
}

impl PropsReport {
    fn collect_failures(&mut self) {
        let mut out = Vec::new();
        let p = &self.positivity;
        if p.nonfinite > 0 {
            out.push(format!("{} non-finite values", p.nonfinite));
        }
        if p.negative > 0 {
            out.push(format!(
                "{} negative values (min {:e})",
                p.negative, p.min_value
            ));
        }
        for (name, s) in [
            ("reciprocal", &self.reciprocity),
            ("isotropic", &self.isotropy),
        ] {
            if s.promised && !s.holds {
                out.push(format!(
                    "promised {name} but the relative difference reaches {:e}",
                    s.max_rel_diff
                ));
            }
        }
        let e = &self.energy;
        let at = format!("at θi {:.2}°, φi {:.0}°", e.at_theta_i_deg, e.at_phi_i_deg);
        match e.verdict {
            EnergyVerdict::Conserves => {}
            EnergyVerdict::Exceeds => out.push(format!(
                "albedo {:.6e} > 1 + {:.1e} {at}",
                e.max_albedo, e.tolerance
            )),
            EnergyVerdict::Unresolved => out.push(format!(
                "albedo {:.3e} ± {:.1e} {at} is not resolved by the quadrature (error \
                 estimate above {ALBEDO_UNRESOLVED}): energy conservation not shown",
                e.max_albedo, e.tolerance
            )),
            EnergyVerdict::NonFinite => out.push(format!(
                "albedo {} ± {} {at} is not a finite number",
                e.max_albedo, e.tolerance
            )),
        }
        self.failures = out;
    }
}

/// Uniform in solid angle over the upper hemisphere (z = u1 by Archimedes' theorem).
fn uniform_hemisphere(rng: &mut SplitMix64) -> Vec3 {
    let z = rng.next_f64();
    let phi = 2.0 * PI * rng.next_f64();
    let r = (1.0 - z * z).max(0.0).sqrt();
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// The direction cases of `spec/hard-cases.md`: horizon, just above/below, normal, tiny
/// tilts, retro-reflection, exact mirror, opposite directions, in-plane pairs.
fn hard_case_pairs() -> Vec<(Vec3, Vec3)> {
    let tilt = |t: f64, phi: f64| Vec3::from_spherical(t, phi);
    let near_horizon = |z: f64, phi: f64| {
        let r = (1.0 - z * z).max(0.0).sqrt();
        Vec3::new(r * phi.cos(), r * phi.sin(), z)
    };
    let a = Vec3::from_spherical(0.7, 0.4);
    let mut dirs = vec![
        Vec3::Z,
        a,
        a.mirror(),
        near_horizon(0.0, 0.3),
        near_horizon(-1e-12, 0.3),
        Vec3::from_spherical(FRAC_PI_2, 2.0),
    ];
    for z in [1e-12, 1e-8, 1e-4] {
        dirs.push(near_horizon(z, 1.1));
    }
    for t in [1e-9, 1e-6, 1e-3] {
        dirs.push(tilt(t, 0.0));
        dirs.push(tilt(t, PI));
    }
    let mut pairs = Vec::new();
    for &wi in &dirs {
        for &wo in &dirs {
            pairs.push((wi, wo));
        }
        pairs.push((wi, wi.mirror()));
        pairs.push((wi, -wi));
    }
    pairs
}

/// Positivity, reciprocity, isotropy and albedo of `brdf` (see [`PropsReport`]).
pub fn props(brdf: &dyn Brdf, options: &PropsOptions) -> PropsReport {
    let nc = brdf.channels().len();
    // The random pairs are drawn again for each pass (same seed, same pairs) so that memory
    // does not grow with `samples`.
    let random_pairs = || {
        let mut rng = SplitMix64::new(options.seed);
        (0..options.samples).map(move |_| {
            let wi = uniform_hemisphere(&mut rng);
            (wi, uniform_hemisphere(&mut rng))
        })
    };

    // Positivity over random and hard-case pairs.
    let mut f = vec![0.0; nc];
    let mut g = vec![0.0; nc];
    let mut pos = Positivity {
        pairs: 0,
        min_value: f64::INFINITY,
        min_at: DirPair::new(Vec3::Z, Vec3::Z),
        negative: 0,
        nonfinite: 0,
    };
    let mut f_max = 0.0f64;
    let tagged_random = random_pairs().map(|p| (p, true));
    let tagged_hard = hard_case_pairs().into_iter().map(|p| (p, false));
    for ((wi, wo), is_random) in tagged_random.chain(tagged_hard) {
        brdf.eval(wi, wo, &mut f);
        pos.pairs += 1;
        for &v in &f {
            if !v.is_finite() {
                pos.nonfinite += 1;
                continue;
            }
            if is_random {
                // The floor's scale comes from the random pairs only: a hard-case pair at
                // the horizon can reach 1e24 and would hide every asymmetry below it.
                f_max = f_max.max(v.abs());
            }
            if v < 0.0 {
                pos.negative += 1;
            }
            if v < pos.min_value {
                pos.min_value = v;
                pos.min_at = DirPair::new(wi, wo);
            }
        }
    }
    if !pos.min_value.is_finite() {
        // Every value was non-finite: report 0 rather than an infinity JSON cannot hold.
        pos.min_value = 0.0;
    }
    let floor = (1e-9 * f_max).max(f64::MIN_POSITIVE);

    // Reciprocity: f(wi, wo) against f(wo, wi).
    let mut recip = Symmetry {
        promised: brdf.is_reciprocal(),
        max_rel_diff: 0.0,
        floor,
        worst: DirPair::new(Vec3::Z, Vec3::Z),
        worst_rotation_deg: None,
        holds: true,
    };
    for (wi, wo) in random_pairs() {
        brdf.eval(wi, wo, &mut f);
        brdf.eval(wo, wi, &mut g);
        let d = max_rel_diff(&f, &g, floor);
        if d > recip.max_rel_diff {
            recip.max_rel_diff = d;
            recip.worst = DirPair::new(wi, wo);
        }
    }
    recip.holds = recip.max_rel_diff <= SYMMETRY_TOLERANCE;

    // Isotropy: both directions rotated about z by a common random angle.
    let mut iso = Symmetry {
        promised: brdf.is_isotropic(),
        max_rel_diff: 0.0,
        floor,
        worst: DirPair::new(Vec3::Z, Vec3::Z),
        worst_rotation_deg: Some(0.0),
        holds: true,
    };
    // The rotation angles come from a second stream so the pairs stay those of the seed.
    let mut angle_rng = SplitMix64::new(options.seed ^ 0x0005_EED0_FA11_A9E5);
    for (wi, wo) in random_pairs() {
        let angle = 2.0 * PI * angle_rng.next_f64();
        brdf.eval(wi, wo, &mut f);
        brdf.eval(wi.rotate_z(angle), wo.rotate_z(angle), &mut g);
        let d = max_rel_diff(&f, &g, floor);
        if d > iso.max_rel_diff {
            iso.max_rel_diff = d;
            iso.worst = DirPair::new(wi, wo);
            iso.worst_rotation_deg = Some(angle.to_degrees());
        }
    }
    iso.holds = iso.max_rel_diff <= SYMMETRY_TOLERANCE;

    let angles = albedo_angle_pairs_deg(brdf);
    let albedo: Vec<AlbedoRow> = angles
        .par_iter()
        .map(|&(t, p)| {
            let e = albedo_estimate(brdf, t.to_radians(), p.to_radians());
            AlbedoRow {
                theta_i_deg: t,
                phi_i_deg: p,
                albedo: e.value,
                error: e.error,
                evaluations: e.evaluations,
            }
        })
        .collect();
    let energy = energy_verdict(&albedo);

    let specular = angles
        .iter()
        .map(|&(t, p)| {
            let wi = Vec3::from_spherical(t.to_radians(), p.to_radians());
            brdf.specular_coefficient(wi)
                .map(|coefficient| SpecularRow {
                    theta_i_deg: t,
                    phi_i_deg: p,
                    coefficient,
                })
        })
        .collect::<Option<Vec<_>>>();
    let mut report = PropsReport {
        specular,
        htsg_terms: brdf.series_terms_max(),
        source: brdf.describe(),
        channels: brdf.channels().names().to_vec(),
        seed: options.seed,
        samples: options.samples,
        positivity: pos,
        reciprocity: recip,
        isotropy: iso,
        albedo,
        energy,
        failures: Vec::new(),
    };
    report.collect_failures();
    report
}

/// The energy verdict over every albedo row and channel: the worst [`EnergyVerdict`], and
/// the albedo it rests on (for `Conserves` and `Exceeds` the largest albedo; for
/// `Unresolved` the largest estimate + error among the unresolved; for `NonFinite` the
/// first non-finite one).
fn energy_verdict(albedo: &[AlbedoRow]) -> Energy {
    let mut energy = Energy {
        max_albedo: 0.0,
        at_theta_i_deg: 0.0,
        at_phi_i_deg: 0.0,
        channel: 0,
        tolerance: ALBEDO_TOLERANCE,
        conserves: true,
        verdict: EnergyVerdict::Conserves,
    };
    // (verdict, rank within the verdict: larger is worse)
    let mut worst: Option<(EnergyVerdict, f64)> = None;
    for row in albedo {
        for (c, (&a, &e)) in row.albedo.iter().zip(&row.error).enumerate() {
            let tol = e.max(ALBEDO_TOLERANCE);
            let this = if !(a.is_finite() && e.is_finite()) {
                (EnergyVerdict::NonFinite, 0.0)
            } else if a > 1.0 + tol {
                (EnergyVerdict::Exceeds, a)
            } else if e > ALBEDO_UNRESOLVED && a + e > 1.0 + ALBEDO_TOLERANCE {
                (EnergyVerdict::Unresolved, a + e)
            } else {
                (EnergyVerdict::Conserves, a)
            };
            let replace = match worst {
                None => true,
                Some((v, rank)) => this.0 < v || (this.0 == v && this.1 > rank),
            };
            if replace {
                worst = Some(this);
                energy.max_albedo = a;
                energy.at_theta_i_deg = row.theta_i_deg;
                energy.at_phi_i_deg = row.phi_i_deg;
                energy.channel = c;
                energy.tolerance = if e.is_finite() { tol } else { e };
            }
        }
    }
    if let Some((v, _)) = worst {
        energy.verdict = v;
    }
    energy.conserves = energy.verdict == EnergyVerdict::Conserves;
    energy
}

/// max over channels of |a − b| / max(|a|, |b|, floor); a non-finite value counts as a
/// total mismatch (1) unless both sides are the same non-finite value.
fn max_rel_diff(a: &[f64], b: &[f64], floor: f64) -> f64 {
    a.iter()
        .zip(b)
        .map(|(&x, &y)| {
            if !(x.is_finite() && y.is_finite()) {
                // NaN is never equal to itself; identical infinities are symmetric.
                return if x == y { 0.0 } else { 1.0 };
            }
            (x - y).abs() / x.abs().max(y.abs()).max(floor)
        })
        .fold(0.0, f64::max)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::Channels;
    use crate::math::{FRAC_1_PI, pow_0_0_is_1, sqr};

    /// Energy-normalized Phong (Lewis 1994): (n+2)/(2π) max(r·wo, 0)^n, r = mirror(wi).
    /// At normal incidence its albedo is 1 exactly; for a lobe that stays above the
    /// horizon it is cos θi (∫ cos^n δ (w·z) dω = r.z · 2π/(n+2)).
    pub(crate) struct TestPhong {
        pub n: f64,
        pub channels: Channels,
    }
    impl TestPhong {
        pub fn new(n: f64) -> Self {
            TestPhong {
                n,
                channels: Channels::default_for(1),
            }
        }
    }
    impl Brdf for TestPhong {
        fn channels(&self) -> &Channels {
            &self.channels
        }
        fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) {
            if wi.z <= 0.0 || wo.z <= 0.0 {
                out.fill(0.0);
                return;
            }
            let c = wi.mirror().dot(wo).max(0.0);
            out[0] = (self.n + 2.0) / (2.0 * PI) * pow_0_0_is_1(c, self.n);
        }
        fn is_isotropic(&self) -> bool {
            true
        }
        fn describe(&self) -> String {
            format!("test phong n={}", self.n)
        }
    }

    /// A peaked lobe with a closed-form albedo: f = D(h) h.z / (4 (wi·h) cos θo) with the
    /// GGX D. Then a(θi) = ∫ D(h) h.z dωh over the h that keep wo above the horizon, and the
    /// GGX cumulative ∫_{θh<T} D h.z dωh = tan²T/(α² + tan²T) gives
    /// a = 1/(2π) ∫ tan²T(φ)/(α² + tan²T(φ)) dφ; at normal incidence T = π/4: 1/(1 + α²).
    struct TestGgxLobe {
        alpha: f64,
        channels: Channels,
    }
    impl Brdf for TestGgxLobe {
        fn channels(&self) -> &Channels {
            &self.channels
        }
        fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) {
            out[0] = 0.0;
            if wi.z <= 0.0 || wo.z <= 0.0 {
                return;
            }
            let Some(h) = (wi + wo).try_normalize() else {
                return;
            };
            let a2 = sqr(self.alpha);
            let d = 1.0 / (PI * a2 * sqr(h.sin2_theta() / a2 + sqr(h.z)));
            out[0] = d * h.z / (4.0 * wi.dot(h) * wo.z);
        }
        fn is_isotropic(&self) -> bool {
            true
        }
        fn is_reciprocal(&self) -> bool {
            false
        }
        fn describe(&self) -> String {
            format!("test ggx lobe alpha={}", self.alpha)
        }
    }

    /// The closed form of [`TestGgxLobe`]'s albedo, by a 1-D integral over φh (trapezoid,
    /// 20,000 nodes: the integrand is smooth and periodic).
    fn ggx_lobe_albedo(alpha: f64, theta_i: f64) -> f64 {
        let n = 20_000;
        let (s, c) = theta_i.sin_cos();
        (0..n)
            .map(|k| {
                let phi = (k as f64 + 0.5) * 2.0 * PI / n as f64;
                let t = 0.5 * (FRAC_PI_2 + (s * phi.cos()).atan2(c));
                let t2 = sqr(t.tan());
                t2 / (sqr(alpha) + t2)
            })
            .sum::<f64>()
            / n as f64
    }

    /// Reciprocal GGX with F = 1 and height-correlated Smith (Heitz 2014): the white
    /// furnace. Its albedo is ≤ 1 and tends to 1 as α → 0.
    struct TestGgx {
        alpha_x: f64,
        alpha_y: f64,
        channels: Channels,
    }
    impl TestGgx {
        fn lambda(&self, v: Vec3) -> f64 {
            let s2 = v.sin2_theta();
            if s2 == 0.0 {
                return 0.0;
            }
            let a2_tan2 = (sqr(self.alpha_x * v.x) + sqr(self.alpha_y * v.y)) / sqr(v.z);
            0.5 * (-1.0 + (1.0 + a2_tan2).sqrt())
        }
    }
    impl Brdf for TestGgx {
        fn channels(&self) -> &Channels {
            &self.channels
        }
        fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) {
            out[0] = 0.0;
            if wi.z <= 0.0 || wo.z <= 0.0 {
                return;
            }
            let Some(h) = (wi + wo).try_normalize() else {
                return;
            };
            let (ax, ay) = (self.alpha_x, self.alpha_y);
            let d = 1.0 / (PI * ax * ay * sqr(sqr(h.x / ax) + sqr(h.y / ay) + sqr(h.z)));
            let g = 1.0 / (1.0 + self.lambda(wi) + self.lambda(wo));
            out[0] = d * g / (4.0 * wi.z * wo.z);
        }
        fn is_isotropic(&self) -> bool {
            self.alpha_x == self.alpha_y
        }
        fn describe(&self) -> String {
            format!("test ggx {} {}", self.alpha_x, self.alpha_y)
        }
    }

    fn ggx(alpha_x: f64, alpha_y: f64) -> TestGgx {
        TestGgx {
            alpha_x,
            alpha_y,
            channels: Channels::default_for(1),
        }
    }

    /// Lambert whose value depends on the order of the pair: not reciprocal.
    struct Skewed {
        channels: Channels,
    }
    impl Brdf for Skewed {
        fn channels(&self) -> &Channels {
            &self.channels
        }
        fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) {
            out[0] = if wi.z <= 0.0 || wo.z <= 0.0 {
                0.0
            } else {
                FRAC_1_PI * (0.5 + 0.1 * wi.z)
            };
        }
        fn is_isotropic(&self) -> bool {
            true
        }
        fn describe(&self) -> String {
            "skewed".into()
        }
    }

    #[test]
    fn gauss_legendre_integrates_polynomials_exactly() {
        for n in [1, 2, 5, 10, 17] {
            let (x, w) = gauss_legendre(n);
            // ∫_{-1}^{1} x^k dx = 2/(k+1) for even k, exact up to degree 2n − 1.
            for k in (0..2 * n).step_by(2) {
                let got: f64 = x.iter().zip(&w).map(|(x, w)| w * x.powi(k as i32)).sum();
                assert!((got - 2.0 / (k as f64 + 1.0)).abs() < 1e-14, "n {n} k {k}");
            }
        }
    }

    #[test]
    fn lambert_albedo_is_rho_at_every_angle() {
        let m = crate::model::Model::parse("lambert:albedo=0.8/0.5/0.2").unwrap();
        for t in albedo_angles_deg() {
            let a = directional_albedo(&m, t.to_radians());
            for (got, want) in a.iter().zip([0.8, 0.5, 0.2]) {
                assert!((got - want).abs() < 1e-12, "θi {t}: {got} vs {want}");
            }
        }
    }

    #[test]
    fn phong_albedo_matches_closed_form() {
        // Worst measured errors: 3e-15 (n = 1, normal), see docs/props.md for the table.
        for n in [1.0, 100.0, 1e4] {
            let b = TestPhong::new(n);
            let a0 = directional_albedo(&b, 0.0)[0];
            assert!((a0 - 1.0).abs() < 1e-6, "n {n}: a(0) = {a0}");
        }
        // Narrow lobes stay above the horizon up to 80°: a = cos θi.
        let b = TestPhong::new(1e4);
        for t in [10.0f64, 30.0, 60.0, 80.0, 85.0] {
            let a = directional_albedo(&b, t.to_radians())[0];
            let want = t.to_radians().cos();
            assert!((a - want).abs() < 1e-6, "θi {t}: {a} vs {want}");
        }
    }

    #[test]
    fn ggx_lobe_albedo_matches_closed_form() {
        for alpha in [0.01, 0.1, 0.5] {
            let b = TestGgxLobe {
                alpha,
                channels: Channels::default_for(1),
            };
            let a0 = directional_albedo(&b, 0.0)[0];
            assert!(
                (a0 - 1.0 / (1.0 + alpha * alpha)).abs() < 1e-6,
                "α {alpha}: {a0}"
            );
            for t in [30.0f64, 60.0, 85.0] {
                let a = directional_albedo(&b, t.to_radians())[0];
                let want = ggx_lobe_albedo(alpha, t.to_radians());
                assert!((a - want).abs() < 1e-6, "α {alpha} θi {t}: {a} vs {want}");
            }
        }
    }

    #[test]
    fn ggx_furnace_albedo_is_near_one_and_converged() {
        let b = ggx(0.01, 0.01);
        for t in [0.0f64, 45.0, 85.0] {
            let e = albedo_estimate(&b, t.to_radians(), 0.0);
            assert!(e.error[0] < 1e-5, "θi {t}: error estimate {}", e.error[0]);
            assert!(
                (0.99..=1.0 + 1e-6).contains(&e.value[0]),
                "θi {t}: {}",
                e.value[0]
            );
        }
    }

    #[test]
    fn plain_rule_agrees_on_broad_lobes() {
        let b = ggx(0.5, 0.5);
        for t in [0.0f64, 40.0, 80.0] {
            let wi = Vec3::from_spherical(t.to_radians(), 0.3);
            let h = half_vector_albedo(&b, wi, HalfVectorRule::FINE)[0];
            let p = plain_albedo(&b, wi, 256, 512)[0];
            assert!((h - p).abs() < 1e-6, "θi {t}: {h} vs {p}");
        }
    }

    #[test]
    fn reciprocity_detector_catches_a_skewed_brdf() {
        let opts = PropsOptions {
            seed: 3,
            samples: 2000,
        };
        let r = props(
            &Skewed {
                channels: Channels::default_for(1),
            },
            &opts,
        );
        assert!(!r.reciprocity.holds);
        // |0.1 (z_i − z_o)| / (0.5 + 0.1 max z) peaks near 0.1/0.6 = 0.167.
        assert!(
            r.reciprocity.max_rel_diff > 0.15,
            "{}",
            r.reciprocity.max_rel_diff
        );
        assert!(r.isotropy.holds);
        let m = crate::model::Model::parse("lambert").unwrap();
        let r = props(&m, &opts);
        assert!(r.reciprocity.holds && r.isotropy.holds);
        assert_eq!(r.reciprocity.max_rel_diff, 0.0);
    }

    #[test]
    fn isotropy_detector_catches_an_anisotropic_brdf() {
        let opts = PropsOptions {
            seed: 5,
            samples: 2000,
        };
        let r = props(&ggx(0.1, 0.3), &opts);
        assert!(!r.isotropy.holds);
        assert!(r.isotropy.max_rel_diff > 0.5, "{}", r.isotropy.max_rel_diff);
        assert!(r.reciprocity.holds, "{}", r.reciprocity.max_rel_diff);
        // Anisotropic sources get a second row set at φi = 90°.
        assert_eq!(r.albedo.len(), 32);
        let r = props(&ggx(0.2, 0.2), &opts);
        assert!(r.isotropy.holds, "{}", r.isotropy.max_rel_diff);
        assert_eq!(r.albedo.len(), 16);
    }

    #[test]
    fn energy_verdict_flags_an_amplifying_source() {
        let opts = PropsOptions {
            seed: 1,
            samples: 100,
        };
        let m = crate::model::Model::parse("lambert:albedo=0.6 + lambert:albedo=0.41").unwrap();
        let r = props(&m, &opts);
        assert!(!r.energy.conserves);
        assert!((r.energy.max_albedo - 1.01).abs() < 1e-12);
        let m = crate::model::Model::parse("lambert:albedo=1").unwrap();
        assert!(props(&m, &opts).energy.conserves);
    }

    #[test]
    fn props_is_deterministic_for_a_seed() {
        let opts = PropsOptions {
            seed: 9,
            samples: 500,
        };
        let b = ggx(0.1, 0.3);
        assert_eq!(props(&b, &opts), props(&b, &opts));
    }

    /// Measures the quadrature against the closed forms and a 4× finer rule; run with
    /// `cargo test measure_albedo_errors -- --ignored --nocapture` to regenerate the table
    /// in docs/props.md.
    #[test]
    #[ignore]
    fn measure_albedo_errors() {
        let reference = HalfVectorRule {
            nodes_per_panel: 24,
            n_phi: 6144,
        };
        let angles = [0.0f64, 30.0, 60.0, 75.0, 85.0];
        let report = |name: &str, b: &dyn Brdf, exact: &dyn Fn(f64) -> Option<f64>| {
            for t in angles {
                let wi = Vec3::from_spherical(t.to_radians(), 0.0);
                let e = albedo_estimate(b, t.to_radians(), 0.0);
                let r = exact(t.to_radians())
                    .unwrap_or_else(|| half_vector_albedo(b, wi, reference)[0]);
                println!(
                    "{name:28} θi {t:4}: a {:.9} |err| {:.1e} est {:.1e} evals {}",
                    e.value[0],
                    (e.value[0] - r).abs(),
                    e.error[0],
                    e.evaluations
                );
            }
        };
        report(
            "lambert 1",
            &crate::model::Model::parse("lambert:albedo=1").unwrap(),
            &|_| Some(1.0),
        );
        for n in [1.0, 100.0, 1e4] {
            report(&format!("phong n={n}"), &TestPhong::new(n), &|t| {
                // a = cos θi while the lobe stays above the horizon (see TestPhong).
                let above = t == 0.0 || n >= 1e4 || (n >= 100.0 && t <= 0.53);
                above.then(|| t.cos())
            });
        }
        for alpha in [0.01, 0.1, 0.5] {
            let b = TestGgxLobe {
                alpha,
                channels: Channels::default_for(1),
            };
            report(&format!("ggx lobe α={alpha}"), &b, &|t| {
                Some(ggx_lobe_albedo(alpha, t))
            });
        }
        for (ax, ay) in [(0.01, 0.01), (0.1, 0.1), (0.01, 0.1), (0.01, 0.5)] {
            report(&format!("ggx furnace α={ax}x{ay}"), &ggx(ax, ay), &|_| {
                None
            });
        }
        println!(
            "evaluations: coarse {} fine {}",
            HalfVectorRule::COARSE.evaluations(),
            HalfVectorRule::FINE.evaluations()
        );
    }

    fn rows(values: &[(f64, f64)]) -> Vec<AlbedoRow> {
        values
            .iter()
            .enumerate()
            .map(|(k, &(a, e))| AlbedoRow {
                theta_i_deg: k as f64,
                phi_i_deg: 0.0,
                albedo: vec![a],
                error: vec![e],
                evaluations: 1,
            })
            .collect()
    }

    /// Issue 20: "albedo 4735 ± 4735" was reported as conserving (4735 ≤ 1 + 4735).
    #[test]
    fn energy_verdicts() {
        let v = |r: &[(f64, f64)]| energy_verdict(&rows(r));
        let e = v(&[(0.5, 1e-5), (0.99, 2e-4)]);
        assert_eq!(
            (e.verdict, e.max_albedo, e.tolerance),
            (EnergyVerdict::Conserves, 0.99, 2e-4)
        );
        assert!(e.conserves);
        // Within the tolerance and a small estimate: conserves, as before.
        assert_eq!(v(&[(1.00005, 1e-5)]).verdict, EnergyVerdict::Conserves);
        assert_eq!(v(&[(1.05, 0.06)]).verdict, EnergyVerdict::Conserves);
        let e = v(&[(4735.0, 4735.0), (0.3, 1e-4)]);
        assert_eq!(
            (e.verdict, e.max_albedo, e.at_theta_i_deg),
            (EnergyVerdict::Unresolved, 4735.0, 0.0)
        );
        assert!(!e.conserves);
        // An unresolved row that cannot reach 1 leaves the verdict alone.
        assert_eq!(v(&[(0.3, 0.5)]).verdict, EnergyVerdict::Conserves);
        // A clear excess outranks an unresolved row and a larger conserving estimate.
        let e = v(&[(4735.0, 4735.0), (1.2, 1e-3), (1.3, 0.5)]);
        assert_eq!((e.verdict, e.max_albedo), (EnergyVerdict::Exceeds, 1.2));
        let e = v(&[(1.2, 1e-3), (f64::INFINITY, f64::NAN), (0.5, 1e-4)]);
        assert_eq!(
            (e.verdict, e.at_theta_i_deg),
            (EnergyVerdict::NonFinite, 1.0)
        );
        assert!(e.max_albedo.is_infinite() && e.tolerance.is_nan());
        assert_eq!(v(&[(0.5, f64::INFINITY)]).verdict, EnergyVerdict::NonFinite);
        assert_eq!(v(&[(f64::NAN, 0.0)]).verdict, EnergyVerdict::NonFinite);
    }

    /// JSON has no infinities: a report's non-finite numbers are strings, never null.
    #[test]
    fn non_finite_numbers_are_strings_in_json() {
        let mut r = rows(&[(f64::INFINITY, f64::NAN), (f64::NEG_INFINITY, 0.5)]);
        r[1].albedo.push(0.25);
        let e = energy_verdict(&r);
        let json = serde_json::to_value((&r, &e)).unwrap();
        assert_eq!(json[0][0]["albedo"], serde_json::json!(["inf"]));
        assert_eq!(json[0][0]["error"], serde_json::json!(["nan"]));
        assert_eq!(json[0][1]["albedo"], serde_json::json!(["-inf", 0.25]));
        assert_eq!(json[1]["max_albedo"], "inf");
        assert_eq!(json[1]["tolerance"], "nan");
        assert_eq!(json[1]["verdict"], "non_finite");
        assert!(!json.to_string().contains("null"), "{json}");
    }
}

#[cfg(test)]
mod batched_tests {
    use super::*;
    use crate::brdf::Channels;
    use crate::grid::parse_grid_spec;
    use crate::table::{Interp, InterpolatedTable};
    use crate::tabulate::{TabulateOptions, tabulate};

    /// A source seen only through [`Brdf::eval`]: the trait's pair-by-pair `eval_pairs`.
    struct PairByPair<'a>(&'a dyn Brdf);
    impl Brdf for PairByPair<'_> {
        fn channels(&self) -> &Channels {
            self.0.channels()
        }
        fn eval(&self, wi: Vec3, wo: Vec3, out: &mut [f64]) {
            self.0.eval(wi, wo, out)
        }
        fn is_isotropic(&self) -> bool {
            self.0.is_isotropic()
        }
        fn describe(&self) -> String {
            self.0.describe()
        }
    }

    /// The albedo quadrature evaluates each azimuth row in one batch; a table's batched
    /// lookups give the bits of its pair-by-pair ones, so the albedo of a table (what
    /// `check` and `pack` report) does not change with the batching, for either mode.
    #[test]
    fn a_tables_batched_albedo_has_the_bits_of_its_pair_by_pair_albedo() {
        let model = crate::model::Model::parse("lambert:albedo=0.3/0.2/0.1 + ggx:alpha=0.15")
            .expect("model");
        // Linear space, and the log space of `pack`'s narrow peaks on its default grid (the
        // grazing θd warp, extended below the horizon), plain and cosine-weighted.
        for spec in [
            "halfdiff3:16x16x32",
            "halfdiff3:16x16x32,warp=sqrt/grazing/linear,at=edge,horizon=extend,space=log:1e-6",
            "halfdiff3:16x16x32,weight=cosine,space=log:0.01",
        ] {
            let grid = parse_grid_spec(spec).expect("grid");
            let table = tabulate(&model, &grid, &TabulateOptions::default()).expect("table");
            for interp in [Interp::Linear, Interp::Nearest] {
                let t = InterpolatedTable {
                    table: &table,
                    interp,
                };
                for deg in [0.0, 37.0, 85.0] {
                    let wi = Vec3::from_spherical(f64::to_radians(deg), 0.4);
                    let batched = half_vector_albedo(&t, wi, HalfVectorRule::COARSE);
                    let single = half_vector_albedo(&PairByPair(&t), wi, HalfVectorRule::COARSE);
                    assert!(batched.iter().all(|a| *a > 0.01), "{batched:?}");
                    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                    assert_eq!(bits(&batched), bits(&single), "{spec} {interp:?} at {deg}°");
                }
            }
        }
    }
}
