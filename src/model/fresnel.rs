//! Fresnel reflectance of `spec/models.md` ("Fresnel"), evaluated at c = wi·h.

use super::params::{
    ChannelCount, ParamDecl, ParamDefault, ParamKind, ParamReader, broadcast, channel_json,
};
use crate::math::{safe_sqrt, sqr};
use crate::{Error, Result};
use serde_json::{Map, Value, json};

/// Schlick's approximation F = f0 + (1 − f0)(1 − c)⁵ (Schlick 1994, Eq. 24).
#[inline]
pub fn fresnel_schlick(f0: f64, cos_theta: f64) -> f64 {
    f0 + (1.0 - f0) * (1.0 - cos_theta).powi(5)
}

/// Exact unpolarized reflectance of a dielectric with relative index `eta` (outside medium 1),
/// in the form of Cook & Torrance 1982 (Eq. in §"Fresnel"), for `cos_theta` in (0, 1].
#[inline]
pub fn fresnel_dielectric(eta: f64, cos_theta: f64) -> f64 {
    let c = cos_theta;
    let e = sqr(eta) - 1.0;
    let g2 = e + sqr(c);
    // g² < 0: no transmitted wave exists (total internal reflection, η < 1).
    if g2 < 0.0 {
        return 1.0;
    }
    // η = 1: g = c exactly (F = 0); sqrt(c²) gave g = 0 and F = 1 once c² underflowed
    // (c < 1e-162, within 1e-162 rad of the horizon).
    let g = if e == 0.0 { c } else { g2.sqrt() };
    // c(g − c) + 1 ≥ 1 − c² > 0 and g + c > 0 for c > 0 and η > 0: no division by zero.
    0.5 * sqr((g - c) / (g + c)) * (1.0 + sqr((c * (g + c) - 1.0) / (c * (g - c) + 1.0)))
}

/// Exact unpolarized reflectance (Rs + Rp)/2 of a conductor with complex index η + ik
/// (relative to the outside medium), for `cos_theta` in (0, 1] (Born & Wolf §14.4;
/// the form of spec/models.md).
#[inline]
pub fn fresnel_conductor(eta: f64, k: f64, cos_theta: f64) -> f64 {
    let c = cos_theta;
    let c2 = sqr(c);
    let s2 = 1.0 - c2;
    let eta2 = sqr(eta);
    let k2 = sqr(k);
    let four_eta2_k2 = 4.0 * eta2 * k2;
    // η + ik = 1 (the outside medium itself): F = 0 at every angle. The general form below
    // degenerates to 0/0 (c < 1e-162, where c² underflows) or to −0.17 (c < 1e-77, where
    // t² = c⁴ underflows) near the horizon.
    let e = eta2 - k2 - 1.0;
    if e == 0.0 && four_eta2_k2 == 0.0 {
        return 0.0;
    }
    // t = η² − k² − s² as (η² − k² − 1) + c²: no cancellation of 1 − c² near the normal.
    let t = e + c2;
    let big_a = (sqr(t) + four_eta2_k2).sqrt();
    // a² = (A + t)/2; for t < 0 (k ≫ η) A + t cancels, so use (A² − t²)/(2(A − t)) = 2η²k²/(A − t).
    let a2 = if t >= 0.0 {
        (big_a + t) / 2.0
    } else {
        0.5 * four_eta2_k2 / (big_a - t)
    };
    let a = safe_sqrt(a2);
    let two_a_c = 2.0 * a * c;
    // Denominator ≥ c² > 0 for c > 0.
    let rs = (big_a - two_a_c + c2) / (big_a + two_a_c + c2);
    let num_p = c2 * big_a - two_a_c * s2 + sqr(s2);
    let den_p = c2 * big_a + two_a_c * s2 + sqr(s2);
    // den_p = 0 only for η = k = 0 at normal incidence, where s and p coincide: Rp = Rs.
    let rp = if den_p > 0.0 { rs * num_p / den_p } else { rs };
    0.5 * (rs + rp)
}

/// Named metals of spec/models.md: RGB η and k.
pub const METALS: &[(&str, [f64; 3], [f64; 3])] = &[
    ("au", [0.143, 0.374, 1.442], [3.983, 2.385, 1.603]),
    ("cu", [0.200, 0.924, 1.102], [3.912, 2.452, 2.142]),
    ("ag", [0.155, 0.117, 0.138], [4.828, 3.122, 2.147]),
    ("al", [1.657, 0.880, 0.521], [9.224, 6.270, 4.837]),
];

pub const SCHLICK_PARAMS: &[ParamDecl] = &[ParamDecl::number("f0", 0.0, 1.0, 0.04)
    .required()
    .per_channel()
    .doc("F0", "1", "reflectance at normal incidence", "Schlick 1994")];
pub const DIELECTRIC_PARAMS: &[ParamDecl] =
    &[ParamDecl::number("ior", 1e-6, 1e6, 1.5).required().doc(
        "η",
        "1",
        "real index of refraction relative to the outside medium (< 1: total internal reflection)",
        "Cook & Torrance 1982",
    )];
pub const CONDUCTOR_PARAMS: &[ParamDecl] = &[
    ParamDecl::number("eta", 0.0, 1e6, 1.0)
        .per_channel()
        .derived_default("required (or nk)")
        .doc(
            "η",
            "1",
            "real part of the complex index",
            "Born & Wolf §14.4",
        ),
    ParamDecl::number("k", 0.0, 1e6, 0.0)
        .per_channel()
        .derived_default("required (or nk)")
        .doc(
            "k",
            "1",
            "imaginary part (extinction coefficient)",
            "Born & Wolf §14.4",
        ),
    ParamDecl::structured(
        "nk",
        ParamKind::DataFile("CSV wavelength_nm,n,k"),
        ParamDefault::Derived("none (eta, k)"),
    )
    .doc(
        "n, k",
        "",
        "tabulated η(λ), k(λ) interpolated linearly at the model's wavelengths_nm (instead of eta, k)",
        "docs/spectral.md",
    ),
];

/// The Fresnel types and their fields, for parsing and listing.
pub const FRESNEL_TYPES: &[(&str, &[ParamDecl], &str)] = &[
    ("none", &[], "F = 1"),
    ("schlick", SCHLICK_PARAMS, "F = f0 + (1 − f0)(1 − c)⁵"),
    (
        "dielectric",
        DIELECTRIC_PARAMS,
        "exact unpolarized dielectric, F = 1 under total internal reflection",
    ),
    (
        "conductor",
        CONDUCTOR_PARAMS,
        "exact unpolarized conductor (η + ik); or a metal name au | cu | ag | al",
    ),
];

/// A Fresnel term with per-channel parameters broadcast to the model's channel count.
#[derive(Clone, Debug, PartialEq)]
pub enum Fresnel {
    None,
    Schlick { f0: Vec<f64> },
    Dielectric { ior: f64 },
    Conductor { eta: Vec<f64>, k: Vec<f64> },
}

impl Fresnel {
    /// F at `cos_theta` = wi·h in (0, 1], channel `ch`.
    #[inline]
    pub fn eval(&self, cos_theta: f64, ch: usize) -> f64 {
        match self {
            Fresnel::None => 1.0,
            Fresnel::Schlick { f0 } => fresnel_schlick(f0[ch], cos_theta),
            Fresnel::Dielectric { ior } => fresnel_dielectric(*ior, cos_theta),
            Fresnel::Conductor { eta, k } => fresnel_conductor(eta[ch], k[ch], cos_theta),
        }
    }

    /// Reads the value of parameter `name` of `reader` (an object `{"type": ..}` or a bare
    /// type / metal name), or the declared default. Lists are left unbroadcast: call
    /// [`Fresnel::broadcast`] once the channel count is known.
    pub(crate) fn read(
        reader: &ParamReader,
        name: &str,
        default_json: &str,
        channels: &mut ChannelCount,
    ) -> Result<Fresnel> {
        let context = reader.context();
        let default_value;
        let value = match reader.raw(name) {
            Some(v) => v,
            None => {
                // The default is a constant of this crate; failing to parse it is a bug.
                default_value = serde_json::from_str::<Value>(default_json).expect("default JSON");
                &default_value
            }
        };
        let mut owned = Map::new();
        let obj = match value {
            Value::String(s) => {
                owned.insert("type".into(), Value::String(s.clone()));
                &owned
            }
            Value::Object(o) => o,
            other => {
                return Err(Error::input(format!(
                    "{context}: {name} = {other} must be an object {{\"type\": ..}} or one of \
                     none | schlick | dielectric | conductor | au | cu | ag | al"
                )));
            }
        };
        let type_name = match obj.get("type") {
            Some(Value::String(s)) => s.as_str(),
            Some(other) => {
                return Err(Error::input(format!(
                    "{context}: {name}.type = {other} is not a string"
                )));
            }
            None => {
                return Err(Error::input(format!(
                    "{context}: {name}.type is required (none | schlick | dielectric | conductor)"
                )));
            }
        };
        if let Some((metal, eta, k)) = METALS.iter().find(|m| m.0 == type_name) {
            if let Some(w) = channels.wavelengths_nm() {
                return Err(Error::input(format!(
                    "{context}: {name} = {metal} is RGB data (3 values) but the channels are {} \
                     spectral samples (wavelengths_nm); give spectral optical constants with \
                     {name}=conductor,nk=@file.csv (docs/spectral.md)",
                    w.len()
                )));
            }
            if let Some(extra) = obj.keys().find(|key| *key != "type") {
                return Err(Error::input(format!(
                    "{context}: {name}.{extra} cannot be combined with the named metal {metal:?} \
                     (use type conductor with eta and k instead)"
                )));
            }
            channels.record(context, &format!("{name} = {metal} (RGB)"), 3)?;
            return Ok(Fresnel::Conductor {
                eta: eta.to_vec(),
                k: k.to_vec(),
            });
        }
        let Some((_, decls, _)) = FRESNEL_TYPES.iter().find(|t| t.0 == type_name) else {
            return Err(Error::input(format!(
                "{context}: {name}.type = {type_name:?} is not one of \
                 none | schlick | dielectric | conductor | au | cu | ag | al"
            )));
        };
        let sub = ParamReader::new(
            context,
            format!("{name}."),
            obj,
            decls,
            &["type"],
            reader.files(),
        )?;
        Ok(match type_name {
            "none" => Fresnel::None,
            "schlick" => Fresnel::Schlick {
                f0: sub.channel("f0", channels)?,
            },
            "dielectric" => Fresnel::Dielectric {
                ior: sub.number("ior")?,
            },
            _ => match sub.file("nk")? {
                None => {
                    let eta = sub.channel("eta", channels)?;
                    let k = sub.channel("k", channels)?;
                    Fresnel::Conductor { eta, k }
                }
                Some(path) => {
                    if let Some(key) = ["eta", "k"].into_iter().find(|k| sub.is_given(k)) {
                        return Err(Error::input(format!(
                            "{context}: {name}.{key} and {name}.nk are both given; \
                             nk = @{path} supplies η and k"
                        )));
                    }
                    let Some(w) = channels.wavelengths_nm() else {
                        return Err(Error::input(format!(
                            "{context}: {name}.nk = @{path} needs the model's wavelengths_nm \
                             (the wavelengths at which to interpolate η and k)"
                        )));
                    };
                    let (eta, k) = reader
                        .files()
                        .optical_constants(path)?
                        .at(w)
                        .map_err(|e| Error::input(format!("{context}: {name}.nk: {e}")))?;
                    Fresnel::Conductor { eta, k }
                }
            },
        })
    }

    /// Repeats scalar per-channel values to `c` channels.
    pub(crate) fn broadcast(self, c: usize) -> Fresnel {
        match self {
            Fresnel::Schlick { f0 } => Fresnel::Schlick {
                f0: broadcast(&f0, c),
            },
            Fresnel::Conductor { eta, k } => Fresnel::Conductor {
                eta: broadcast(&eta, c),
                k: broadcast(&k, c),
            },
            other => other,
        }
    }

    /// Canonical JSON (named metals are written out as their η and k).
    pub fn to_json(&self) -> Value {
        match self {
            Fresnel::None => json!({"type": "none"}),
            Fresnel::Schlick { f0 } => json!({"type": "schlick", "f0": channel_json(f0)}),
            Fresnel::Dielectric { ior } => json!({"type": "dielectric", "ior": ior}),
            Fresnel::Conductor { eta, k } => {
                json!({"type": "conductor", "eta": channel_json(eta), "k": channel_json(k)})
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dielectric_normal_incidence_is_r0() {
        // ((η − 1)/(η + 1))² at c = 1 (Born & Wolf).
        let f = fresnel_dielectric(1.5, 1.0);
        assert!((f - 0.04).abs() < 1e-15, "{f}");
        assert_eq!(fresnel_dielectric(1.0, 0.3), 0.0);
        assert_eq!(fresnel_dielectric(1.0 / 1.5, 0.5), 1.0);
    }

    #[test]
    fn conductor_with_k_zero_is_the_dielectric() {
        for &eta in &[1.2, 1.5, 3.0, 0.7] {
            for i in 1..=20 {
                let c = i as f64 / 20.0;
                let a = fresnel_conductor(eta, 0.0, c);
                let b = fresnel_dielectric(eta, c);
                assert!((a - b).abs() < 1e-13, "eta {eta} c {c}: {a} vs {b}");
            }
        }
    }

    #[test]
    fn conductor_normal_incidence_closed_form() {
        // R(0) = ((η − 1)² + k²)/((η + 1)² + k²).
        let (eta, k) = (0.143, 3.983);
        let want = (sqr(eta - 1.0) + sqr(k)) / (sqr(eta + 1.0) + sqr(k));
        assert!((fresnel_conductor(eta, k, 1.0) - want).abs() < 1e-15);
        // k ≫ η: nearly a perfect mirror, and the cancellation-free a² keeps it in [0, 1].
        let f = fresnel_conductor(1e-3, 1e6, 0.3);
        assert!(f > 0.999_99 && f <= 1.0, "{f}");
        assert_eq!(fresnel_conductor(0.0, 0.0, 1.0), 1.0);
    }
}
