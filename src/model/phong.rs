//! Phong and Blinn–Phong lobes (spec/models.md).

use super::params::{ModelDecl, ParamDecl, ParamReader, broadcast, channel_json};
use crate::Result;
use crate::brdf::Channels;
use crate::geometry::Vec3;
use crate::math::{PI, pow_0_0_is_1};
use serde_json::{Value, json};

const EXPONENT_RANGE: (f64, f64) = (0.0, 1e6);

pub const PHONG_PARAMS: &[ParamDecl] = &[
    ParamDecl::number("albedo", 0.0, 1.0, 0.5)
        .per_channel()
        .doc(
            "ρ",
            "1",
            "specular reflectance (k_s for norm none)",
            "Lewis 1994",
        ),
    ParamDecl::number("exponent", EXPONENT_RANGE.0, EXPONENT_RANGE.1, 32.0).doc(
        "n",
        "1",
        "Phong exponent (0: ρN everywhere, 0⁰ = 1)",
        "Phong 1975",
    ),
    ParamDecl::choice("norm", &["energy", "none"], "energy").doc(
        "N",
        "",
        "energy: N = (n+2)/(2π) (modified Phong, Lewis 1994); none: N = 1",
        "Lewis 1994",
    ),
    super::params::WAVELENGTHS_NM,
];

pub const PHONG_DECL: ModelDecl = ModelDecl {
    name: "phong",
    aliases: &[],
    summary: "Phong lobe around the mirror direction",
    formula: "ρ N max(r·wo, 0)^n, r = (−wi.x, −wi.y, wi.z)",
    citation: "Phong 1975; Lewis 1994",
    params: PHONG_PARAMS,
    isotropic: "always",
    reciprocal: true,
    tabulable: true,
};

/// f = ρ N max(r·wo, 0)^n.
#[derive(Clone, Debug, PartialEq)]
pub struct Phong {
    pub albedo: Vec<f64>,
    pub exponent: f64,
    /// True for N = (n+2)/(2π), false for N = 1.
    pub energy_norm: bool,
    pub(crate) channels: Channels,
}

impl Phong {
    pub(crate) fn from_params(r: &ParamReader) -> Result<Phong> {
        let mut cc = r.channel_count()?;
        let albedo = r.channel("albedo", &mut cc)?;
        let c = cc.count();
        Ok(Phong {
            albedo: broadcast(&albedo, c),
            exponent: r.number("exponent")?,
            energy_norm: r.word("norm")? == "energy",
            channels: cc.channels(c),
        })
    }

    pub(crate) fn to_json(&self) -> Value {
        json!({
            "model": "phong",
            "albedo": channel_json(&self.albedo),
            "exponent": self.exponent,
            "norm": if self.energy_norm { "energy" } else { "none" },
        })
    }

    #[inline]
    pub(crate) fn eval_channels(&self, wi: Vec3, wo: Vec3, first: usize, out: &mut [f64]) {
        let n = self.exponent;
        // r·wo with r = (−wi.x, −wi.y, wi.z), written symmetrically in wi and wo.
        let r_dot_wo = wi.z * wo.z - wi.x * wo.x - wi.y * wo.y;
        // Modified Phong normalization (Lewis 1994, Eq. 9).
        let norm = if self.energy_norm {
            (n + 2.0) / (2.0 * PI)
        } else {
            1.0
        };
        // max(·, 0)^n with 0⁰ = 1, in log space for huge n.
        let lobe = norm * pow_0_0_is_1(r_dot_wo.max(0.0), n);
        for (o, a) in out.iter_mut().zip(&self.albedo[first..]) {
            *o = a * lobe;
        }
    }
}

pub const BLINN_PHONG_PARAMS: &[ParamDecl] = &[
    ParamDecl::number("albedo", 0.0, 1.0, 0.5)
        .per_channel()
        .doc("ρ", "1", "specular reflectance", "Blinn 1977"),
    ParamDecl::number("exponent", EXPONENT_RANGE.0, EXPONENT_RANGE.1, 32.0).doc(
        "n",
        "1",
        "exponent of h.z",
        "Blinn 1977",
    ),
    super::params::WAVELENGTHS_NM,
];

pub const BLINN_PHONG_DECL: ModelDecl = ModelDecl {
    name: "blinn-phong",
    aliases: &[],
    summary: "normalized Blinn–Phong lobe around the normal in half-vector space",
    formula: "ρ (n+8)/(8π) (h.z)^n",
    citation: "Blinn 1977; Akenine-Möller et al., Real-Time Rendering",
    params: BLINN_PHONG_PARAMS,
    isotropic: "always",
    reciprocal: true,
    tabulable: true,
};

/// f = ρ (n+8)/(8π) (h.z)^n.
#[derive(Clone, Debug, PartialEq)]
pub struct BlinnPhong {
    pub albedo: Vec<f64>,
    pub exponent: f64,
    pub(crate) channels: Channels,
}

impl BlinnPhong {
    pub(crate) fn from_params(r: &ParamReader) -> Result<BlinnPhong> {
        let mut cc = r.channel_count()?;
        let albedo = r.channel("albedo", &mut cc)?;
        let c = cc.count();
        Ok(BlinnPhong {
            albedo: broadcast(&albedo, c),
            exponent: r.number("exponent")?,
            channels: cc.channels(c),
        })
    }

    pub(crate) fn to_json(&self) -> Value {
        json!({
            "model": "blinn-phong",
            "albedo": channel_json(&self.albedo),
            "exponent": self.exponent,
        })
    }

    #[inline]
    pub(crate) fn eval_channels(&self, wi: Vec3, wo: Vec3, first: usize, out: &mut [f64]) {
        let n = self.exponent;
        let Some(h) = (wi + wo).try_normalize() else {
            // wi = −wo: no half vector (spec: f = 0).
            out.fill(0.0);
            return;
        };
        // (n+8)/(8π) normalization (Akenine-Möller et al., RTR 3rd ed., Eq. 7.49).
        let lobe = (n + 8.0) / (8.0 * PI) * pow_0_0_is_1(h.z.max(0.0), n);
        for (o, a) in out.iter_mut().zip(&self.albedo[first..]) {
            *o = a * lobe;
        }
    }
}
