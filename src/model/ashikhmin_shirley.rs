//! Ashikhmin–Shirley anisotropic Phong BRDF (Ashikhmin & Shirley 2000; spec/models.md).

use super::finite_large;
use super::params::{ModelDecl, ParamDecl, ParamReader, broadcast, channel_json};
use crate::Result;
use crate::brdf::Channels;
use crate::geometry::{Vec3, half_vector, one_minus_cos_theta_d};
use crate::math::{PI, pow_0_0_is_1, sqr};
use serde_json::{Value, json};

pub const PARAMS: &[ParamDecl] = &[
    ParamDecl::number("rs", 0.0, 1.0, 0.05).per_channel().doc(
        "R_s",
        "1",
        "specular reflectance at normal incidence",
        "Ashikhmin & Shirley 2000",
    ),
    ParamDecl::number("rd", 0.0, 1.0, 0.0).per_channel().doc(
        "R_d",
        "1",
        "diffuse reflectance",
        "Ashikhmin & Shirley 2000",
    ),
    ParamDecl::number("nu", 0.0, 1e6, 100.0).doc(
        "n_u",
        "1",
        "Phong exponent along the tangent x",
        "Ashikhmin & Shirley 2000",
    ),
    ParamDecl::number("nv", 0.0, 1e6, 100.0).doc(
        "n_v",
        "1",
        "Phong exponent along the bitangent y",
        "Ashikhmin & Shirley 2000",
    ),
    super::params::WAVELENGTHS_NM,
];

pub const DECL: ModelDecl = ModelDecl {
    name: "ashikhmin-shirley",
    aliases: &[],
    summary: "anisotropic Phong specular with Schlick Fresnel plus a coupled diffuse term",
    formula: "sqrt((nu+1)(nv+1))/(8π) h.z^e F(wi·h)/((wi·h) max(c_i, c_o)) + f_d",
    citation: "Ashikhmin & Shirley 2000, Eqs. 4–5",
    params: PARAMS,
    isotropic: "when nu = nv",
    reciprocal: true,
    tabulable: true,
};

#[derive(Clone, Debug, PartialEq)]
pub struct AshikhminShirley {
    pub rs: Vec<f64>,
    pub rd: Vec<f64>,
    pub nu: f64,
    pub nv: f64,
    pub(crate) channels: Channels,
}

impl AshikhminShirley {
    pub(crate) fn from_params(r: &ParamReader) -> Result<AshikhminShirley> {
        let mut cc = r.channel_count()?;
        let rs = r.channel("rs", &mut cc)?;
        let rd = r.channel("rd", &mut cc)?;
        let c = cc.count();
        Ok(AshikhminShirley {
            rs: broadcast(&rs, c),
            rd: broadcast(&rd, c),
            nu: r.number("nu")?,
            nv: r.number("nv")?,
            channels: cc.channels(c),
        })
    }

    pub(crate) fn to_json(&self) -> Value {
        json!({
            "model": "ashikhmin-shirley",
            "rs": channel_json(&self.rs),
            "rd": channel_json(&self.rd),
            "nu": self.nu,
            "nv": self.nv,
        })
    }

    pub fn is_isotropic(&self) -> bool {
        self.nu == self.nv
    }

    #[inline]
    pub(crate) fn eval_channels(&self, wi: Vec3, wo: Vec3, first: usize, out: &mut [f64]) {
        // k = wi·h = wo·h = cos θd, the same number both ways round (reciprocity at grazing).
        let Some((h, k)) = half_vector(wi, wo) else {
            // wi = −wo: no half vector.
            out.fill(0.0);
            return;
        };
        // 1 − h.z² as h.x² + h.y² (no cancellation); 0 at the normal, where e is 0/0 but
        // h.z = 1 makes h.z^e = 1 for any e.
        let sin2_h = h.sin2_theta();
        let e = if sin2_h == 0.0 {
            0.0
        } else {
            (self.nu * sqr(h.x) + self.nv * sqr(h.y)) / sin2_h
        };
        // Eq. 4: the specular lobe without its Fresnel factor; h.z^e in log space (e ≤ 1e6).
        let lobe = if k <= 0.0 {
            // Back-facing half vector (rounding only above the horizon).
            0.0
        } else {
            let norm = ((self.nu + 1.0) * (self.nv + 1.0)).sqrt() / (8.0 * PI);
            // One division at a time: k max(c_i, c_o) can underflow at grazing opposite pairs.
            finite_large(norm * pow_0_0_is_1(h.z, e) / k / wi.z.max(wo.z))
        };
        // 1 − k without cancellation: k rounds to just above 1 near retro-reflection, and
        // (1 − k)⁵ then made F (and f with rs = 0) negative.
        let one_minus_k5 = one_minus_cos_theta_d(wi, wo, k).powi(5);
        // Eq. 5: the diffuse term's angular factor.
        let diffuse_angular =
            (1.0 - (1.0 - wi.z / 2.0).powi(5)) * (1.0 - (1.0 - wo.z / 2.0).powi(5));
        for (j, o) in out.iter_mut().enumerate() {
            let ch = first + j;
            let rs = self.rs[ch];
            // Schlick Fresnel with R_s as F0 (Eq. 4).
            let fresnel = rs + (1.0 - rs) * one_minus_k5;
            let f_d = 28.0 * self.rd[ch] / (23.0 * PI) * (1.0 - rs) * diffuse_angular;
            *o = finite_large(lobe * fresnel + f_d);
        }
    }
}
