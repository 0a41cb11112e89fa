//! Microfacet BRDF (spec/models.md "Microfacet details"): distributions, Smith and V-cavity
//! shadowing, and the model scale · D(h) G F(wi·h) / (4 c_i c_o) (Walter et al. 2007, Eq. 20).

use super::finite_large;
use super::fresnel::Fresnel;
use super::params::{
    Alias, ModelDecl, ParamDecl, ParamDefault, ParamKind, ParamReader, broadcast, channel_json,
};
use crate::brdf::Channels;
use crate::geometry::{Vec3, half_vector};
use crate::math::{PI, erfc, sqr};
use crate::{Error, Result};
use serde_json::{Value, json};

/// 1/a² = α_v² tan²θ_v = (α_x² v.x² + α_y² v.y²)/v.z² (Heitz 2014, Eq. 80): written without
/// tanθ so that normal incidence gives 1/a² = 0 (a = ∞) instead of a division by zero.
#[inline]
fn inv_a2(alpha_x: f64, alpha_y: f64, v: Vec3) -> f64 {
    (sqr(alpha_x * v.x) + sqr(alpha_y * v.y)) / sqr(v.z)
}

/// The GGX (Trowbridge–Reitz) distribution of normals, anisotropic form.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GgxDistribution {
    pub alpha_x: f64,
    pub alpha_y: f64,
}

impl GgxDistribution {
    /// D(h) = 1/(π α_x α_y (h.x²/α_x² + h.y²/α_y² + h.z²)²) (Heitz 2014, Eq. 85).
    #[inline]
    pub fn d(&self, h: Vec3) -> f64 {
        let e = sqr(h.x / self.alpha_x) + sqr(h.y / self.alpha_y) + sqr(h.z);
        1.0 / (PI * self.alpha_x * self.alpha_y * sqr(e))
    }

    /// Smith Λ(v) = (−1 + sqrt(1 + 1/a²))/2 (Heitz 2014, Eq. 86).
    #[inline]
    pub fn lambda(&self, v: Vec3) -> f64 {
        let x = inv_a2(self.alpha_x, self.alpha_y, v);
        let s = (1.0 + x).sqrt();
        // For small 1/a², −1 + sqrt(1 + x) cancels: use the equal x/(1 + sqrt(1 + x)).
        if x < 1.0 {
            0.5 * x / (1.0 + s)
        } else {
            0.5 * (s - 1.0)
        }
    }

    /// G1(v) = 1/(1 + Λ(v)).
    #[inline]
    pub fn g1(&self, v: Vec3) -> f64 {
        1.0 / (1.0 + self.lambda(v))
    }
}

/// How Beckmann's Smith G1 is computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BeckmannG1 {
    /// Λ from erf (Walter et al. 2007, Eq. 25).
    Exact,
    /// Walter et al. 2007's rational fit (Eq. 27), as used by several renderers.
    Rational,
}

/// The Beckmann distribution of normals, anisotropic form.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BeckmannDistribution {
    pub alpha_x: f64,
    pub alpha_y: f64,
    pub g1_form: BeckmannG1,
}

impl BeckmannDistribution {
    /// D(h) = exp(−(h.x²/α_x² + h.y²/α_y²)/h.z²)/(π α_x α_y h.z⁴) (Heitz 2014, Eq. 83).
    #[inline]
    pub fn d(&self, h: Vec3) -> f64 {
        let e = (sqr(h.x / self.alpha_x) + sqr(h.y / self.alpha_y)) / sqr(h.z);
        let falloff = (-e).exp();
        // The exponential underflowed: D = 0, even where h.z⁴ also underflows (no 0/0).
        if falloff == 0.0 {
            return 0.0;
        }
        falloff / (PI * self.alpha_x * self.alpha_y) / sqr(h.z) / sqr(h.z)
    }

    /// Smith Λ(v): exact (erf(a) − 1)/2 + exp(−a²)/(2a√π), or from the rational G1.
    #[inline]
    pub fn lambda(&self, v: Vec3) -> f64 {
        match self.g1_form {
            BeckmannG1::Exact => {
                let x = inv_a2(self.alpha_x, self.alpha_y, v);
                // Normal incidence: a = ∞, Λ = 0.
                if x == 0.0 {
                    return 0.0;
                }
                let a = 1.0 / x.sqrt();
                // erf(a) − 1 = −erfc(a), without the cancellation of 1 − erf for large a
                // (Walter et al. 2007, Eq. 25).
                0.5 * (-erfc(a) + (-sqr(a)).exp() / (a * PI.sqrt()))
            }
            BeckmannG1::Rational => 1.0 / self.g1(v) - 1.0,
        }
    }

    /// G1(v) = 1/(1 + Λ(v)), or the rational fit directly.
    #[inline]
    pub fn g1(&self, v: Vec3) -> f64 {
        match self.g1_form {
            BeckmannG1::Exact => 1.0 / (1.0 + self.lambda(v)),
            BeckmannG1::Rational => {
                // a = ∞ at the normal (1/a² = 0), a = 0 when 1/a² overflows at the horizon.
                let a = 1.0 / inv_a2(self.alpha_x, self.alpha_y, v).sqrt();
                if a >= 1.6 {
                    return 1.0;
                }
                // Walter et al. 2007, Eq. 27.
                (3.535 * a + 2.181 * sqr(a)) / (1.0 + 2.276 * a + 2.577 * sqr(a))
            }
        }
    }
}

/// The microfacet normal distribution of a [`Microfacet`] model.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Distribution {
    Ggx(GgxDistribution),
    Beckmann(BeckmannDistribution),
}

impl Distribution {
    #[inline]
    pub fn d(&self, h: Vec3) -> f64 {
        match self {
            Distribution::Ggx(g) => g.d(h),
            Distribution::Beckmann(b) => b.d(h),
        }
    }
    #[inline]
    pub fn lambda(&self, v: Vec3) -> f64 {
        match self {
            Distribution::Ggx(g) => g.lambda(v),
            Distribution::Beckmann(b) => b.lambda(v),
        }
    }
    #[inline]
    pub fn g1(&self, v: Vec3) -> f64 {
        match self {
            Distribution::Ggx(g) => g.g1(v),
            Distribution::Beckmann(b) => b.g1(v),
        }
    }
    fn alphas(&self) -> (f64, f64) {
        match self {
            Distribution::Ggx(g) => (g.alpha_x, g.alpha_y),
            Distribution::Beckmann(b) => (b.alpha_x, b.alpha_y),
        }
    }
}

/// The V-cavity masking–shadowing G = min(1, 2 h.z c_o/(wo·h), 2 h.z c_i/(wi·h))
/// (Torrance & Sparrow 1967; Cook & Torrance 1982, Eq. 9). Requires wi·h, wo·h > 0.
#[inline]
pub fn v_cavity_g(wi: Vec3, wo: Vec3, h: Vec3, cos_i_h: f64, cos_o_h: f64) -> f64 {
    let g_o = 2.0 * h.z * wo.z / cos_o_h;
    let g_i = 2.0 * h.z * wi.z / cos_i_h;
    1.0f64.min(g_o).min(g_i)
}

/// D · G/(k c_i c_o) for the microfacet and Torrance–Sparrow models, with k their constant
/// (4 or π). G is divided by the cosines before D multiplies it: near the horizon G is as
/// small as c (1e-300) and D · G went subnormal (losing digits, so f(wi, wo) ≠ f(wo, wi)),
/// while G/c stays of order 1. Dividing by the larger cosine first makes the result
/// exactly symmetric in c_i and c_o. D = 0 gives 0 even where G/(c_i c_o) overflows.
#[inline]
pub(crate) fn d_times_g_over_cosines(d: f64, g: f64, k: f64, c_i: f64, c_o: f64) -> f64 {
    if d == 0.0 {
        return 0.0;
    }
    d * (g / (k * c_i.max(c_o)) / c_i.min(c_o))
}

/// Masking–shadowing G(wi, wo).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Shadowing {
    /// G = 1/(1 + Λ(wi) + Λ(wo)) (Heitz 2014, Eq. 99).
    SmithCorrelated,
    /// G = G1(wi) G1(wo) (Heitz 2014, Eq. 98).
    SmithSeparable,
    /// See [`v_cavity_g`].
    VCavity,
}

impl Shadowing {
    const NAMES: &'static [&'static str] = &["smith-correlated", "smith-separable", "v-cavity"];

    fn name(self) -> &'static str {
        match self {
            Shadowing::SmithCorrelated => "smith-correlated",
            Shadowing::SmithSeparable => "smith-separable",
            Shadowing::VCavity => "v-cavity",
        }
    }

    #[inline]
    pub fn g(
        self,
        dist: &Distribution,
        wi: Vec3,
        wo: Vec3,
        h: Vec3,
        cos_i_h: f64,
        cos_o_h: f64,
    ) -> f64 {
        match self {
            // Λ(wi) + Λ(wo) summed first: the same rounding for (wi, wo) and (wo, wi).
            Shadowing::SmithCorrelated => 1.0 / (1.0 + (dist.lambda(wi) + dist.lambda(wo))),
            Shadowing::SmithSeparable => dist.g1(wi) * dist.g1(wo),
            Shadowing::VCavity => v_cavity_g(wi, wo, h, cos_i_h, cos_o_h),
        }
    }
}

const ROUGHNESS_CITE: &str = "Walter et al. 2007; Heitz 2014";

/// The microfacet model's parameters.
pub const PARAMS: &[ParamDecl] = &[
    ParamDecl::choice("distribution", &["ggx", "beckmann"], "ggx").doc(
        "D",
        "",
        "microfacet normal distribution",
        ROUGHNESS_CITE,
    ),
    ParamDecl::number("alpha", 1e-6, 10.0, 0.2).doc(
        "α",
        "1",
        "isotropic roughness (RMS slope for beckmann); exclusive with alpha_x/alpha_y",
        ROUGHNESS_CITE,
    ),
    ParamDecl::number("alpha_x", 1e-6, 10.0, 0.2)
        .derived_default("alpha")
        .doc(
            "α_x",
            "1",
            "roughness along the tangent x (give with alpha_y)",
            "Heitz 2014",
        ),
    ParamDecl::number("alpha_y", 1e-6, 10.0, 0.2)
        .derived_default("alpha")
        .doc(
            "α_y",
            "1",
            "roughness along the bitangent y (give with alpha_x)",
            "Heitz 2014",
        ),
    ParamDecl::choice("shadowing", Shadowing::NAMES, "smith-correlated").doc(
        "G",
        "",
        "masking-shadowing: height-correlated Smith, separable Smith, or V-cavity",
        "Heitz 2014; Cook & Torrance 1982",
    ),
    ParamDecl::choice("g1", &["exact", "rational"], "exact").doc(
        "G1",
        "",
        "Beckmann Smith G1: exact (erf) or Walter's rational fit (beckmann only)",
        "Walter et al. 2007, Eq. 27",
    ),
    ParamDecl::structured(
        "fresnel",
        ParamKind::Fresnel,
        ParamDefault::Json(r#"{"type":"none"}"#),
    )
    .doc(
        "F",
        "",
        "Fresnel term evaluated at wi·h",
        "spec/models.md Fresnel",
    ),
    ParamDecl::number("scale", 0.0, 1e6, 1.0)
        .per_channel()
        .doc("", "1", "overall factor", ""),
    super::params::WAVELENGTHS_NM,
];

pub const DECL: ModelDecl = ModelDecl {
    name: "microfacet",
    aliases: &[
        Alias {
            name: "ggx",
            preset: &[("distribution", "ggx")],
        },
        Alias {
            name: "beckmann",
            preset: &[("distribution", "beckmann")],
        },
    ],
    summary: "GGX or Beckmann microfacet reflection with Smith or V-cavity shadowing",
    formula: "scale · D(h) G F(wi·h) / (4 c_i c_o)",
    citation: "Walter et al. 2007; Heitz 2014",
    params: PARAMS,
    isotropic: "when alpha_x = alpha_y",
    reciprocal: true,
    tabulable: true,
};

/// The microfacet model.
#[derive(Clone, Debug, PartialEq)]
pub struct Microfacet {
    pub distribution: Distribution,
    pub shadowing: Shadowing,
    pub fresnel: Fresnel,
    pub scale: Vec<f64>,
    pub(crate) channels: Channels,
}

impl Microfacet {
    pub(crate) fn from_params(r: &ParamReader) -> Result<Microfacet> {
        let ctx = r.context();
        let (alpha_x, alpha_y) = match (
            r.is_given("alpha"),
            r.is_given("alpha_x"),
            r.is_given("alpha_y"),
        ) {
            (true, false, false) | (false, false, false) => {
                let a = r.number("alpha")?;
                (a, a)
            }
            (false, true, true) => (r.number("alpha_x")?, r.number("alpha_y")?),
            (true, _, _) => {
                let other = if r.is_given("alpha_x") {
                    "alpha_x"
                } else {
                    "alpha_y"
                };
                return Err(Error::input(format!(
                    "{ctx}: alpha = {} and {other} = {} are both given; use either alpha \
                     (isotropic) or alpha_x and alpha_y (anisotropic)",
                    r.raw("alpha").map(Value::to_string).unwrap_or_default(),
                    r.raw(other).map(Value::to_string).unwrap_or_default(),
                )));
            }
            (false, x, _) => {
                let (given, missing) = if x {
                    ("alpha_x", "alpha_y")
                } else {
                    ("alpha_y", "alpha_x")
                };
                return Err(Error::input(format!(
                    "{ctx}: {given} = {} is given without {missing} (give both, or alpha alone)",
                    r.raw(given).map(Value::to_string).unwrap_or_default()
                )));
            }
        };
        let g1 = r.word("g1")?;
        let distribution = match r.word("distribution")? {
            "ggx" => {
                if g1 == "rational" {
                    return Err(Error::input(format!(
                        "{ctx}: g1 = \"rational\" applies to distribution beckmann only \
                         (distribution = ggx has an exact closed-form G1)"
                    )));
                }
                Distribution::Ggx(GgxDistribution { alpha_x, alpha_y })
            }
            _ => Distribution::Beckmann(BeckmannDistribution {
                alpha_x,
                alpha_y,
                g1_form: if g1 == "rational" {
                    BeckmannG1::Rational
                } else {
                    BeckmannG1::Exact
                },
            }),
        };
        let shadowing = match r.word("shadowing")? {
            "smith-correlated" => Shadowing::SmithCorrelated,
            "smith-separable" => Shadowing::SmithSeparable,
            _ => Shadowing::VCavity,
        };
        let mut cc = r.channel_count()?;
        let fresnel = Fresnel::read(r, "fresnel", r#"{"type":"none"}"#, &mut cc)?;
        let scale = r.channel("scale", &mut cc)?;
        let c = cc.count();
        Ok(Microfacet {
            distribution,
            shadowing,
            fresnel: fresnel.broadcast(c),
            scale: broadcast(&scale, c),
            channels: cc.channels(c),
        })
    }

    pub(crate) fn to_json(&self) -> Value {
        let (ax, ay) = self.distribution.alphas();
        let (dist, g1) = match self.distribution {
            Distribution::Ggx(_) => ("ggx", "exact"),
            Distribution::Beckmann(b) => (
                "beckmann",
                if b.g1_form == BeckmannG1::Rational {
                    "rational"
                } else {
                    "exact"
                },
            ),
        };
        let mut v = json!({
            "model": "microfacet",
            "distribution": dist,
            "shadowing": self.shadowing.name(),
            "g1": g1,
            "fresnel": self.fresnel.to_json(),
            "scale": channel_json(&self.scale),
        });
        if ax == ay {
            v["alpha"] = ax.into();
        } else {
            v["alpha_x"] = ax.into();
            v["alpha_y"] = ay.into();
        }
        v
    }

    pub fn is_isotropic(&self) -> bool {
        let (ax, ay) = self.distribution.alphas();
        ax == ay
    }

    /// Channels `first..first + out.len()`; requires wi.z > 0 and wo.z > 0.
    #[inline]
    pub(crate) fn eval_channels(&self, wi: Vec3, wo: Vec3, first: usize, out: &mut [f64]) {
        // wi·h = wo·h = cos θd, the same number both ways round (reciprocity at grazing).
        let Some((h, cos_d)) = half_vector(wi, wo) else {
            // wi = −wo: no half vector (cannot happen above the horizon; kept for safety).
            out.fill(0.0);
            return;
        };
        // G = 0 when a direction sees the back of the microfacet (spec: wi·h ≤ 0 or wo·h ≤ 0).
        if cos_d <= 0.0 {
            out.fill(0.0);
            return;
        }
        let d = self.distribution.d(h);
        let g = self
            .shadowing
            .g(&self.distribution, wi, wo, h, cos_d, cos_d);
        let dg = finite_large(d_times_g_over_cosines(d, g, 4.0, wi.z, wo.z));
        for (j, o) in out.iter_mut().enumerate() {
            let ch = first + j;
            *o = finite_large(self.scale[ch] * self.fresnel.eval(cos_d, ch) * dg);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// ∫ g(h) dω over the upper hemisphere by the midpoint rule in (θ, φ).
    fn hemisphere_integral(n_theta: usize, n_phi: usize, g: impl Fn(Vec3) -> f64) -> f64 {
        let (dt, dp) = (0.5 * PI / n_theta as f64, 2.0 * PI / n_phi as f64);
        let mut sum = 0.0;
        for i in 0..n_theta {
            let theta = (i as f64 + 0.5) * dt;
            let mut ring = 0.0;
            for j in 0..n_phi {
                ring += g(Vec3::from_spherical(theta, (j as f64 + 0.5) * dp));
            }
            sum += ring * theta.sin();
        }
        sum * dt * dp
    }

    fn distributions() -> Vec<(&'static str, Distribution)> {
        vec![
            (
                "ggx iso",
                Distribution::Ggx(GgxDistribution {
                    alpha_x: 0.3,
                    alpha_y: 0.3,
                }),
            ),
            (
                "ggx aniso",
                Distribution::Ggx(GgxDistribution {
                    alpha_x: 0.2,
                    alpha_y: 0.5,
                }),
            ),
            (
                "beckmann iso",
                Distribution::Beckmann(BeckmannDistribution {
                    alpha_x: 0.3,
                    alpha_y: 0.3,
                    g1_form: BeckmannG1::Exact,
                }),
            ),
            (
                "beckmann aniso",
                Distribution::Beckmann(BeckmannDistribution {
                    alpha_x: 0.5,
                    alpha_y: 0.2,
                    g1_form: BeckmannG1::Exact,
                }),
            ),
        ]
    }

    #[test]
    fn projected_microfacet_area_is_one() {
        // ∫ D(h) h.z dω_h = 1 (Heitz 2014, Eq. 4).
        for (name, d) in distributions() {
            let total = hemisphere_integral(1500, 400, |h| d.d(h) * h.z);
            assert!((total - 1.0).abs() < 2e-4, "{name}: {total}");
        }
    }

    #[test]
    fn smith_lambda_matches_its_distribution() {
        // 1 + Λ(v) = ∫ max(0, v·h) D(h) dω_h / v.z (Heitz 2014, Eqs. 23 and 72): ties the
        // exact Λ of each distribution, anisotropic included, to its D.
        for (name, d) in distributions() {
            for v in [
                Vec3::from_spherical(0.4, 0.3),
                Vec3::from_spherical(1.2, 1.0),
                Vec3::from_spherical(1.45, 2.5),
            ] {
                let projected = hemisphere_integral(1500, 600, |h| v.dot(h).max(0.0) * d.d(h));
                let want = projected / v.z;
                let got = 1.0 + d.lambda(v);
                assert!(
                    (got / want - 1.0).abs() < 5e-4,
                    "{name} at {v:?}: {got} vs {want}"
                );
            }
        }
    }

    #[test]
    fn rational_g1_is_close_to_exact() {
        // Walter et al. 2007 quote the fit's error as below 0.35 %.
        let exact = BeckmannDistribution {
            alpha_x: 0.5,
            alpha_y: 0.5,
            g1_form: BeckmannG1::Exact,
        };
        let fit = BeckmannDistribution {
            g1_form: BeckmannG1::Rational,
            ..exact
        };
        for i in 1..90 {
            let v = Vec3::from_spherical(i as f64 * PI / 180.0, 0.7);
            let (a, b) = (exact.g1(v), fit.g1(v));
            assert!((a - b).abs() <= 0.0036 * a, "θ = {i}°: {a} vs {b}");
        }
    }

    #[test]
    fn normal_incidence_has_no_shadowing() {
        for (_, d) in distributions() {
            assert_eq!(d.lambda(Vec3::Z), 0.0);
            assert_eq!(d.g1(Vec3::Z), 1.0);
        }
    }
}
