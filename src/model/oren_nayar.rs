//! Oren–Nayar rough diffuse reflection, qualitative model (Oren & Nayar 1994, Eq. 30).

use super::finite_large;
use super::params::{ModelDecl, ParamDecl, ParamReader, broadcast, channel_json};
use crate::Result;
use crate::brdf::Channels;
use crate::geometry::Vec3;
use crate::math::{FRAC_1_PI, FRAC_PI_2, sqr};
use serde_json::{Value, json};

pub const PARAMS: &[ParamDecl] = &[
    ParamDecl::number("albedo", 0.0, 1.0, 0.5)
        .per_channel()
        .doc("ρ", "1", "diffuse reflectance", "Oren & Nayar 1994"),
    ParamDecl::number("sigma", 0.0, FRAC_PI_2, 0.3).doc(
        "σ",
        "rad",
        "standard deviation of the facet slope angle",
        "Oren & Nayar 1994",
    ),
    super::params::WAVELENGTHS_NM,
];

pub const DECL: ModelDecl = ModelDecl {
    name: "oren-nayar",
    aliases: &[],
    summary: "rough diffuse reflection (qualitative model)",
    formula: "ρ/π (A + B max(wi.x wo.x + wi.y wo.y, 0)/max(c_i, c_o))",
    citation: "Oren & Nayar 1994, Eq. 30",
    params: PARAMS,
    isotropic: "always",
    reciprocal: true,
    tabulable: true,
};

#[derive(Clone, Debug, PartialEq)]
pub struct OrenNayar {
    pub albedo: Vec<f64>,
    pub sigma: f64,
    /// A = 1 − 0.5σ²/(σ² + 0.33).
    a: f64,
    /// B = 0.45σ²/(σ² + 0.09).
    b: f64,
    pub(crate) channels: Channels,
}

impl OrenNayar {
    pub(crate) fn from_params(r: &ParamReader) -> Result<OrenNayar> {
        let mut cc = r.channel_count()?;
        let albedo = r.channel("albedo", &mut cc)?;
        let c = cc.count();
        let sigma = r.number("sigma")?;
        let s2 = sqr(sigma);
        Ok(OrenNayar {
            albedo: broadcast(&albedo, c),
            sigma,
            a: 1.0 - 0.5 * s2 / (s2 + 0.33),
            b: 0.45 * s2 / (s2 + 0.09),
            channels: cc.channels(c),
        })
    }

    pub(crate) fn to_json(&self) -> Value {
        json!({"model": "oren-nayar", "albedo": channel_json(&self.albedo), "sigma": self.sigma})
    }

    #[inline]
    pub(crate) fn eval_channels(&self, wi: Vec3, wo: Vec3, first: usize, out: &mut [f64]) {
        // sinθ_i sinθ_o cos(φ_i − φ_o), without angles.
        let cos_phi_term = (wi.x * wo.x + wi.y * wo.y).max(0.0);
        // max(c_i, c_o) > 0 above the horizon. The B term grows like 1/max(c_i, c_o) at
        // grazing pairs (sin α tan β of Eq. 30), past f64 within ~1e-308 of the horizon.
        let factor = finite_large(FRAC_1_PI * (self.a + self.b * cos_phi_term / wi.z.max(wo.z)));
        for (o, a) in out.iter_mut().zip(&self.albedo[first..]) {
            *o = a * factor;
        }
    }
}
