//! Lambertian diffuse reflection and the ideal mirror (spec/models.md).

use super::params::{ModelDecl, ParamDecl, ParamReader, broadcast, channel_json};
use crate::Result;
use crate::brdf::Channels;
use crate::geometry::Vec3;
use crate::math::FRAC_1_PI;
use serde_json::{Value, json};

pub const LAMBERT_PARAMS: &[ParamDecl] = &[
    ParamDecl::number("albedo", 0.0, 1.0, 0.5)
        .per_channel()
        .doc("ρ", "1", "diffuse reflectance (albedo)", "Lambert 1760"),
    super::params::WAVELENGTHS_NM,
];

pub const LAMBERT_DECL: ModelDecl = ModelDecl {
    name: "lambert",
    aliases: &[],
    summary: "ideal diffuse reflection",
    formula: "ρ/π",
    citation: "Lambert 1760",
    params: LAMBERT_PARAMS,
    isotropic: "always",
    reciprocal: true,
    tabulable: true,
};

/// f = ρ/π.
#[derive(Clone, Debug, PartialEq)]
pub struct Lambert {
    pub albedo: Vec<f64>,
    pub(crate) channels: Channels,
}

impl Lambert {
    pub(crate) fn from_params(r: &ParamReader) -> Result<Lambert> {
        let mut cc = r.channel_count()?;
        let albedo = r.channel("albedo", &mut cc)?;
        let c = cc.count();
        Ok(Lambert {
            albedo: broadcast(&albedo, c),
            channels: cc.channels(c),
        })
    }

    pub(crate) fn to_json(&self) -> Value {
        json!({"model": "lambert", "albedo": channel_json(&self.albedo)})
    }

    #[inline]
    pub(crate) fn eval_channels(&self, _wi: Vec3, _wo: Vec3, first: usize, out: &mut [f64]) {
        for (o, a) in out.iter_mut().zip(&self.albedo[first..]) {
            *o = a * FRAC_1_PI;
        }
    }
}

pub const MIRROR_PARAMS: &[ParamDecl] = &[
    ParamDecl::number("albedo", 0.0, 1.0, 1.0)
        .per_channel()
        .doc("ρ", "1", "reflectance of the specular delta", ""),
    super::params::WAVELENGTHS_NM,
];

pub const MIRROR_DECL: ModelDecl = ModelDecl {
    name: "mirror",
    aliases: &[],
    summary: "ideal specular reflection (a Dirac delta: not tabulable; use e.g. ggx:alpha=0.001)",
    formula: "ρ δ(wo − (−wi.x, −wi.y, wi.z)) / c_i",
    citation: "",
    params: MIRROR_PARAMS,
    isotropic: "always",
    reciprocal: true,
    tabulable: false,
};

/// The ideal mirror: a Dirac delta at wo = (−wi.x, −wi.y, wi.z). It parses, reports its
/// albedo, and refuses pointwise evaluation (see `Model::check_tabulable`).
#[derive(Clone, Debug, PartialEq)]
pub struct Mirror {
    pub albedo: Vec<f64>,
    pub(crate) channels: Channels,
}

impl Mirror {
    pub(crate) fn from_params(r: &ParamReader) -> Result<Mirror> {
        let mut cc = r.channel_count()?;
        let albedo = r.channel("albedo", &mut cc)?;
        let c = cc.count();
        Ok(Mirror {
            albedo: broadcast(&albedo, c),
            channels: cc.channels(c),
        })
    }

    pub(crate) fn to_json(&self) -> Value {
        json!({"model": "mirror", "albedo": channel_json(&self.albedo)})
    }
}
