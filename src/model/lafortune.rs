//! Lafortune's generalized cosine lobes (Lafortune et al. 1997) with the optional
//! normalization of Ngan et al. 2005 (spec/models.md).

use super::finite_large;
use super::params::{
    ModelDecl, ParamDecl, ParamDefault, ParamKind, ParamReader, broadcast, channel_json, fmt_num,
};
use crate::brdf::Channels;
use crate::geometry::Vec3;
use crate::math::{FRAC_1_PI, PI, pow_0_0_is_1};
use crate::{Error, Result};
use serde_json::{Value, json};

/// Bound on |cx|, |cy|, |cz|: published fits stay within a few units.
const COEFF_MAX: f64 = 100.0;
/// Bound on the number of lobes (published fits use 1–3); caps the work per evaluation.
pub const MAX_LOBES: usize = 64;

/// The fields of one lobe.
pub const LOBE_PARAMS: &[ParamDecl] = &[
    ParamDecl::number("cx", -COEFF_MAX, COEFF_MAX, 0.0)
        .required()
        .per_channel()
        .doc("C_x", "1", "weight of wi.x wo.x", "Lafortune et al. 1997"),
    ParamDecl::number("cy", -COEFF_MAX, COEFF_MAX, 0.0)
        .required()
        .per_channel()
        .doc("C_y", "1", "weight of wi.y wo.y", "Lafortune et al. 1997"),
    ParamDecl::number("cz", -COEFF_MAX, COEFF_MAX, 0.0)
        .required()
        .per_channel()
        .doc("C_z", "1", "weight of wi.z wo.z", "Lafortune et al. 1997"),
    ParamDecl::number("n", 0.0, 1e6, 0.0)
        .required()
        .per_channel()
        .doc("n", "1", "lobe exponent (0⁰ = 1)", "Lafortune et al. 1997"),
    ParamDecl::number("albedo", 0.0, 1e6, 1.0)
        .per_channel()
        .doc("ρ_s", "1", "lobe weight", "Lafortune et al. 1997"),
];

pub const PARAMS: &[ParamDecl] = &[
    ParamDecl::number("diffuse", 0.0, 1.0, 0.0)
        .per_channel()
        .doc("ρ_d", "1", "diffuse reflectance", "Lafortune et al. 1997"),
    ParamDecl::structured("lobes", ParamKind::Lobes, ParamDefault::Required).doc(
        "",
        "",
        "the lobes, each {cx, cy, cz, n, albedo}",
        "Lafortune et al. 1997",
    ),
    ParamDecl::choice("norm", &["none", "ngan"], "none").doc(
        "N",
        "",
        "none: N = 1; ngan: N = (n+2)/(2π max(cz², cx²)^(n/2)), isotropic lobes only",
        "Ngan et al. 2005",
    ),
    super::params::WAVELENGTHS_NM,
];

pub const DECL: ModelDecl = ModelDecl {
    name: "lafortune",
    aliases: &[],
    summary: "sum of generalized cosine lobes plus a diffuse term",
    formula: "ρ_d/π + Σ albedo N max(cx wi.x wo.x + cy wi.y wo.y + cz wi.z wo.z, 0)^n",
    citation: "Lafortune et al. 1997; Ngan et al. 2005",
    params: PARAMS,
    isotropic: "when cx = cy in every lobe",
    reciprocal: true,
    tabulable: true,
};

/// One lobe; every field has one value per channel.
#[derive(Clone, Debug, PartialEq)]
pub struct LafortuneLobe {
    pub cx: Vec<f64>,
    pub cy: Vec<f64>,
    pub cz: Vec<f64>,
    pub n: Vec<f64>,
    pub albedo: Vec<f64>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct Lafortune {
    pub diffuse: Vec<f64>,
    pub lobes: Vec<LafortuneLobe>,
    /// True for Ngan's normalization, false for N = 1.
    pub ngan_norm: bool,
    pub(crate) channels: Channels,
}

impl Lafortune {
    pub(crate) fn from_params(r: &ParamReader) -> Result<Lafortune> {
        let ctx = r.context();
        let mut cc = r.channel_count()?;
        let diffuse = r.channel("diffuse", &mut cc)?;
        let items = match r.raw("lobes") {
            Some(Value::Array(items)) => items,
            Some(other) => {
                return Err(Error::input(format!(
                    "{ctx}: lobes = {other} is not a list of lobe objects {{cx, cy, cz, n, albedo}}"
                )));
            }
            None => {
                return Err(Error::input(format!(
                    "{ctx}: lobes is required (a list of {{cx, cy, cz, n, albedo}}; compact form \
                     lobe=cx:cy:cz:n[:albedo])"
                )));
            }
        };
        if items.len() > MAX_LOBES {
            return Err(Error::input(format!(
                "{ctx}: lobes has {} entries; at most {MAX_LOBES} are accepted",
                items.len()
            )));
        }
        let mut raw_lobes = Vec::with_capacity(items.len());
        for (i, item) in items.iter().enumerate() {
            let Value::Object(obj) = item else {
                return Err(Error::input(format!(
                    "{ctx}: lobes[{i}] = {item} is not an object {{cx, cy, cz, n, albedo}}"
                )));
            };
            let lr = ParamReader::new(
                ctx,
                format!("lobes[{i}]."),
                obj,
                LOBE_PARAMS,
                &[],
                r.files(),
            )?;
            raw_lobes.push([
                lr.channel("cx", &mut cc)?,
                lr.channel("cy", &mut cc)?,
                lr.channel("cz", &mut cc)?,
                lr.channel("n", &mut cc)?,
                lr.channel("albedo", &mut cc)?,
            ]);
        }
        let c = cc.count();
        let ngan_norm = r.word("norm")? == "ngan";
        let lobes: Vec<LafortuneLobe> = raw_lobes
            .iter()
            .map(|[cx, cy, cz, n, albedo]| LafortuneLobe {
                cx: broadcast(cx, c),
                cy: broadcast(cy, c),
                cz: broadcast(cz, c),
                n: broadcast(n, c),
                albedo: broadcast(albedo, c),
            })
            .collect();
        if ngan_norm {
            for (i, lobe) in lobes.iter().enumerate() {
                for ch in 0..c {
                    if lobe.cx[ch] != lobe.cy[ch] {
                        return Err(Error::input(format!(
                            "{ctx}: lobes[{i}].cx = {} differs from lobes[{i}].cy = {} (channel \
                             {ch}); norm = ngan is defined for isotropic lobes (cx = cy) only",
                            fmt_num(lobe.cx[ch]),
                            fmt_num(lobe.cy[ch])
                        )));
                    }
                }
            }
        }
        Ok(Lafortune {
            diffuse: broadcast(&diffuse, c),
            lobes,
            ngan_norm,
            channels: cc.channels(c),
        })
    }

    pub(crate) fn to_json(&self) -> Value {
        let lobes: Vec<Value> = self
            .lobes
            .iter()
            .map(|l| {
                json!({
                    "cx": channel_json(&l.cx),
                    "cy": channel_json(&l.cy),
                    "cz": channel_json(&l.cz),
                    "n": channel_json(&l.n),
                    "albedo": channel_json(&l.albedo),
                })
            })
            .collect();
        json!({
            "model": "lafortune",
            "diffuse": channel_json(&self.diffuse),
            "norm": if self.ngan_norm { "ngan" } else { "none" },
            "lobes": lobes,
        })
    }

    pub fn is_isotropic(&self) -> bool {
        self.lobes.iter().all(|l| l.cx == l.cy)
    }

    /// N max(x, 0)^n of one lobe at channel `ch`, for x = cx wi.x wo.x + cy wi.y wo.y + cz wi.z wo.z.
    #[inline]
    fn lobe_value(&self, lobe: &LafortuneLobe, ch: usize, x: f64) -> f64 {
        let n = lobe.n[ch];
        if !self.ngan_norm {
            // Lafortune et al. 1997, Eq. 3 with N = 1; 0⁰ = 1; log space for huge n. With
            // |C| > 1 and huge n the value can exceed f64: the largest finite value is returned.
            return finite_large(pow_0_0_is_1(x.max(0.0), n));
        }
        // Ngan et al. 2005: N = (n+2)/(2π max(cz², cx²)^(n/2)).
        let norm = (n + 2.0) / (2.0 * PI);
        if n == 0.0 {
            // 0⁰ = 1 for both the lobe and max(cz², cx²)^0.
            return norm;
        }
        if x <= 0.0 {
            return 0.0;
        }
        // x > 0 implies max(|cz|, |cx|) > 0 (cy = cx under ngan). x^n / m^n = exp(n (ln x − ln m)):
        // in log space, because m^n and x^n overflow separately for large n while their
        // ratio stays in range.
        let m = lobe.cz[ch].abs().max(lobe.cx[ch].abs());
        finite_large(norm * (n * (x.ln() - m.ln())).exp())
    }

    #[inline]
    pub(crate) fn eval_channels(&self, wi: Vec3, wo: Vec3, first: usize, out: &mut [f64]) {
        // Products symmetric in wi and wo, so that f(wi, wo) = f(wo, wi) bit for bit.
        let (px, py, pz) = (wi.x * wo.x, wi.y * wo.y, wi.z * wo.z);
        for (j, o) in out.iter_mut().enumerate() {
            let ch = first + j;
            let mut sum = self.diffuse[ch] * FRAC_1_PI;
            for lobe in &self.lobes {
                let x = lobe.cx[ch] * px + lobe.cy[ch] * py + lobe.cz[ch] * pz;
                sum += lobe.albedo[ch] * self.lobe_value(lobe, ch, x);
            }
            // Lobes near f64::MAX can add up past it: keep the largest finite value.
            *o = finite_large(sum);
        }
    }
}
