//! Torrance–Sparrow in the seed slide's form (spec/models.md): scale · D G F/(π c_i c_o).

use super::finite_large;
use super::fresnel::Fresnel;
use super::microfacet::{d_times_g_over_cosines, v_cavity_g};
use super::params::{
    ModelDecl, ParamDecl, ParamDefault, ParamKind, ParamReader, broadcast, channel_json,
};
use crate::Result;
use crate::brdf::Channels;
use crate::geometry::{Vec3, half_vector};
use crate::math::{PI, sqr};
use serde_json::{Value, json};

const DEFAULT_FRESNEL: &str = r#"{"type":"dielectric","ior":1.5}"#;

pub const PARAMS: &[ParamDecl] = &[
    ParamDecl::number("m", 1e-6, 10.0, 0.2).doc(
        "m",
        "1",
        "RMS slope of the Beckmann facet distribution",
        "Torrance & Sparrow 1967; Cook & Torrance 1982",
    ),
    ParamDecl::structured(
        "fresnel",
        ParamKind::Fresnel,
        ParamDefault::Json(DEFAULT_FRESNEL),
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
    name: "torrance-sparrow",
    aliases: &[],
    summary: "Torrance–Sparrow / Cook–Torrance specular, slide form (Beckmann D, V-cavity G)",
    formula: "scale · D G F(wi·h)/(π c_i c_o), D = exp(−tan²β/m²)/(4 m² cos⁴β)",
    citation: "Torrance & Sparrow 1967; Cook & Torrance 1982",
    params: PARAMS,
    isotropic: "always",
    reciprocal: true,
    tabulable: true,
};

#[derive(Clone, Debug, PartialEq)]
pub struct TorranceSparrow {
    pub m: f64,
    pub fresnel: Fresnel,
    pub scale: Vec<f64>,
    pub(crate) channels: Channels,
}

impl TorranceSparrow {
    pub(crate) fn from_params(r: &ParamReader) -> Result<TorranceSparrow> {
        let mut cc = r.channel_count()?;
        let fresnel = Fresnel::read(r, "fresnel", DEFAULT_FRESNEL, &mut cc)?;
        let scale = r.channel("scale", &mut cc)?;
        let c = cc.count();
        Ok(TorranceSparrow {
            m: r.number("m")?,
            fresnel: fresnel.broadcast(c),
            scale: broadcast(&scale, c),
            channels: cc.channels(c),
        })
    }

    pub(crate) fn to_json(&self) -> Value {
        json!({
            "model": "torrance-sparrow",
            "m": self.m,
            "fresnel": self.fresnel.to_json(),
            "scale": channel_json(&self.scale),
        })
    }

    #[inline]
    pub(crate) fn eval_channels(&self, wi: Vec3, wo: Vec3, first: usize, out: &mut [f64]) {
        // wi·h = wo·h = cos θd, the same number both ways round (reciprocity at grazing).
        let Some((h, cos_d)) = half_vector(wi, wo) else {
            // wi = −wo: no half vector.
            out.fill(0.0);
            return;
        };
        // Back-facing microfacet (rounding only, above the horizon): G = 0.
        if cos_d <= 0.0 {
            out.fill(0.0);
            return;
        }
        // tan²β = (h.x² + h.y²)/h.z², cos⁴β = h.z⁴ (no cancellation near the normal).
        let falloff = (-h.tan2_theta() / sqr(self.m)).exp();
        // Underflowed exponential: D = 0 even where h.z⁴ also underflows (no 0/0).
        let d = if falloff == 0.0 {
            0.0
        } else {
            falloff / (4.0 * sqr(self.m)) / sqr(h.z) / sqr(h.z)
        };
        let g = v_cavity_g(wi, wo, h, cos_d, cos_d);
        let dg = finite_large(d_times_g_over_cosines(d, g, PI, wi.z, wo.z));
        for (j, o) in out.iter_mut().enumerate() {
            let ch = first + j;
            *o = finite_large(self.scale[ch] * self.fresnel.eval(cos_d, ch) * dg);
        }
    }
}
