//! The hard cases of `spec/hard-cases.md` as a standing suite (issue 7): every model and
//! variant of `spec/models.md` at extreme parameters, evaluated at the hard direction pairs
//! (normal incidence, grazing, z = 1e-300, the horizon and below, retro, mirror, wi = −wo,
//! φ seams, near-pole tilts); invalid parameters through the CLI; tables on every grid kind
//! through every codec and file format; the measured files of `../shared/data`; and a
//! property test over random parameters and directions.
//!
//! Outcome required everywhere (hard-cases.md): finite, ≥ 0, exactly 0 below the horizon,
//! f(wi, wo) = f(wo, wi) to 1e-12 where the spec promises reciprocity (all models, models.md
//! "Conventions"), and no panic.

mod common;

use assert_cmd::Command;
use brdfpack::brdf::{Brdf, Channels};
use brdfpack::codec::{CodecRequest, CodecSpec, quantize::Quantizer};
use brdfpack::geometry::Vec3;
use brdfpack::grid::parse_grid_spec;
use brdfpack::io::exr::{ExrCompression, ExrOptions, ExrSampleType};
use brdfpack::io::merl::MerlLookup;
use brdfpack::io::rgl::RglBsdf;
use brdfpack::io::{self, OutputFormat};
use brdfpack::math::{FRAC_PI_2, PI};
use brdfpack::model::fresnel::{FRESNEL_TYPES, METALS, fresnel_conductor, fresnel_dielectric};
use brdfpack::model::{CATALOG, Model, ParamKind};
use brdfpack::table::{Interp, Provenance, Table};
use brdfpack::tabulate::{TabulateOptions, tabulate};
use proptest::prelude::*;
use serde_json::Value;
use std::path::Path;

// ---------------------------------------------------------------------------------------------
// The catalogue: one spec per model and variant, at extreme parameters.
// ---------------------------------------------------------------------------------------------

/// Every model and variant of spec/models.md, isotropic and anisotropic, at the parameter
/// extremes of hard-cases.md (roughness 1e-6 .. 10, albedo 0 and 1, exponents 0 .. 1e6,
/// IOR 1, < 1 and huge, conductors with k = 0 and k ≫ η). `catalogue_covers_every_model`
/// fails when a model, alias, choice value, Fresnel type or metal has no case here.
const MODEL_CASES: &[&str] = &[
    // lambert
    "lambert:albedo=0",
    "lambert:albedo=1",
    "lambert:albedo=0.8/0.5/0.2",
    // mirror: a Dirac delta, refused for pointwise evaluation (its eval writes zeros).
    "mirror:albedo=0.9",
    // phong (both normalizations, 0^0 = 1 and pow underflow)
    "phong:albedo=1,exponent=0,norm=energy",
    "phong:albedo=1,exponent=1e6,norm=none",
    "phong:albedo=0.5/0.4/0.3,exponent=32",
    // blinn-phong
    "blinn-phong:albedo=1,exponent=0",
    "blinn-phong:albedo=1,exponent=1e6",
    // torrance-sparrow (default dielectric Fresnel 1.5)
    "torrance-sparrow:m=1e-4",
    "torrance-sparrow:m=0.5,fresnel=none",
    "torrance-sparrow:m=1e-6,fresnel=dielectric,ior=1",
    "torrance-sparrow:m=1,fresnel=schlick,f0=1",
    "torrance-sparrow:m=10,fresnel=au,scale=1e6",
    // microfacet: GGX
    "ggx:alpha=1e-4",
    "ggx:alpha=1e-6,fresnel=au",
    "ggx:alpha=0.0005,fresnel=cu",
    "ggx:alpha=1",
    "ggx:alpha=10,shadowing=smith-separable,fresnel=ag",
    "ggx:alpha_x=1e-4,alpha_y=1,fresnel=al",
    "ggx:alpha_x=1,alpha_y=1e-6,shadowing=v-cavity",
    "ggx:alpha=0.3,fresnel=dielectric,ior=1",
    "ggx:alpha=0.3,fresnel=dielectric,ior=1e-6",
    "ggx:alpha=0.3,fresnel=dielectric,ior=0.67",
    "ggx:alpha=1e-4,shadowing=v-cavity,fresnel=dielectric,ior=1e6",
    "ggx:alpha=0.3,fresnel=conductor,eta=0,k=0",
    "ggx:alpha=0.3,fresnel=conductor,eta=1.5,k=0",
    "torrance-sparrow:m=1e-6,fresnel=conductor,eta=1,k=0",
    "ggx:alpha=0.3,fresnel=conductor,eta=1e-3,k=1e6",
    "ggx:alpha=0.3,fresnel=conductor,eta=1e6,k=1e6,scale=1e6",
    "ggx:alpha=0.2,fresnel=schlick,f0=0/0.5/1",
    "microfacet:distribution=ggx,alpha=0.2,shadowing=smith-correlated,g1=exact,fresnel=none",
    // microfacet: Beckmann
    "beckmann:alpha=1e-4",
    "beckmann:alpha=1,g1=rational",
    "beckmann:alpha=1e-6,g1=rational,shadowing=smith-separable",
    "beckmann:alpha_x=10,alpha_y=1e-4,g1=exact,shadowing=smith-separable,fresnel=au",
    "microfacet:distribution=beckmann,alpha_x=0.05,alpha_y=0.5,shadowing=v-cavity",
    // ward: the three normalizations, isotropic and anisotropic
    "ward:variant=ward,rho_s=1,rho_d=1,alpha_x=1e-4,alpha_y=1e-4",
    "ward:variant=ward,rho_s=1,alpha_x=1e-6,alpha_y=10",
    "ward:variant=duer,rho_s=1,alpha_x=1e-4,alpha_y=1e-4",
    "ward:variant=duer,rho_s=1,rho_d=0.5,alpha_x=10,alpha_y=1e-4",
    "ward:variant=balanced,rho_s=1,alpha_x=1e-6,alpha_y=1e-6",
    "ward:variant=balanced,rho_s=1,rho_d=1,alpha_x=0.05,alpha_y=1",
    // oren-nayar
    "oren-nayar:albedo=1,sigma=0",
    "oren-nayar:albedo=1,sigma=1.5707963267948966",
    "oren-nayar:albedo=0,sigma=0.5",
    // ashikhmin-shirley
    "ashikhmin-shirley:rs=1,rd=1,nu=0,nv=0",
    "ashikhmin-shirley:rs=0,rd=1,nu=1e6,nv=1e6",
    "ashikhmin-shirley:rs=1,rd=1,nu=0,nv=1e6",
    "ashikhmin-shirley:rs=0.05/0.5/1,rd=0,nu=10,nv=1000",
    // lafortune (none and ngan normalizations, retro lobes, huge exponents)
    "lafortune:diffuse=1,lobe=-1:-1:1:1e6",
    "lafortune:lobe=100:100:100:1e6:1e6",
    "lafortune:norm=ngan,diffuse=0.2,lobe=-1:-1:0.95:20/18/7,lobe=0.5:0.5:0.3:3:0.2",
    "lafortune:norm=ngan,lobe=100:100:1e-3:1e6",
    "lafortune:lobe=-0.8:-1.1:0.9:15,lobe=1:1:1:0",
    // htsg (smooth to very rough, dielectric and conductor, spectral)
    "htsg",
    "htsg:sigma0=0.01,tau=3",
    "htsg:sigma0=1,tau=2,eta_re=0.2/0.9/1.1,eta_im=3.9/2.4/2.1",
    "htsg:sigma0=0.5,tau=0.5,eta_re=1,eta_im=0,uniform_diffuse=1",
    "htsg:sigma0=0.2,tau=5,wavelengths=0.4/0.5/0.6/0.7,eta_re=1.5",
    // sum
    "lambert:albedo=0.1 + ggx:alpha=1e-4,fresnel=au",
    "oren-nayar:albedo=0.5 + ward:variant=duer,alpha_x=1e-4,alpha_y=0.5 + htsg:sigma0=0.05",
];

/// Invalid parameters: each must make the CLI exit 2 with a `brdfpack:` message naming the
/// parameter (second field), with nothing on stdout. NaN, ±inf, negative where meaningless,
/// out of range, wrong word, contradictory or incomplete.
const INVALID_CASES: &[(&str, &str)] = &[
    ("lambert:albedo=nan", "albedo"),
    ("lambert:albedo=-0.1", "albedo"),
    ("lambert:albedo=1.01", "albedo"),
    ("lambert:albedo=0.5/inf/0.2", "albedo"),
    ("phong:exponent=-1", "exponent"),
    ("phong:exponent=inf", "exponent"),
    ("phong:norm=bogus", "norm"),
    ("blinn-phong:exponent=nan", "exponent"),
    ("torrance-sparrow:m=0", "m"),
    ("torrance-sparrow:m=-1", "m"),
    ("ggx:alpha=nan", "alpha"),
    ("ggx:alpha=-0.2", "alpha"),
    ("ggx:alpha=inf", "alpha"),
    ("ggx:alpha=0", "alpha"),
    ("ggx:alpha=11", "alpha"),
    ("ggx:alpha_x=0.1", "alpha_y"),
    ("ggx:alpha=0.1,alpha_y=0.2", "alpha_y"),
    ("ggx:g1=rational", "g1"),
    ("ggx:shadowing=none", "shadowing"),
    ("microfacet:distribution=phong", "distribution"),
    ("ggx:scale=-1", "scale"),
    ("ggx:fresnel=dielectric,ior=0", "ior"),
    ("ggx:fresnel=dielectric,ior=nan", "ior"),
    ("ggx:fresnel=conductor,eta=-1,k=1", "eta"),
    ("ggx:fresnel=schlick,f0=2", "f0"),
    ("ward:alpha_x=0,alpha_y=0.1", "alpha_x"),
    ("ward:rho_s=2", "rho_s"),
    ("ward:variant=bogus", "variant"),
    ("oren-nayar:sigma=-0.1", "sigma"),
    ("oren-nayar:sigma=2", "sigma"),
    ("ashikhmin-shirley:nu=-1", "nu"),
    ("ashikhmin-shirley:nv=inf", "nv"),
    ("ashikhmin-shirley:rs=1.5", "rs"),
    ("lafortune:diffuse=2,lobe=1:1:1:1", "diffuse"),
    ("lafortune:lobe=1:1:1:-2", "n"),
    ("htsg:sigma0=0", "sigma0"),
    ("htsg:tau=-1", "tau"),
    ("htsg:eta_re=0", "eta_re"),
    ("htsg:wavelengths=nan", "wavelengths"),
];

fn parse(spec: &str) -> Model {
    Model::parse(spec).unwrap_or_else(|e| panic!("{spec}: {e}"))
}

fn models() -> Vec<(&'static str, Model)> {
    MODEL_CASES.iter().map(|s| (*s, parse(s))).collect()
}

fn eval(b: &dyn Brdf, wi: Vec3, wo: Vec3) -> Vec<f64> {
    let mut out = vec![f64::NAN; b.channels().len()];
    b.eval(wi, wo, &mut out);
    out
}

/// Every object with a "model" key in a canonical JSON tree (sum terms included).
fn model_objects(v: &Value, out: &mut Vec<serde_json::Map<String, Value>>) {
    match v {
        Value::Object(o) => {
            if o.contains_key("model") {
                out.push(o.clone());
            }
            o.values().for_each(|x| model_objects(x, out));
        }
        Value::Array(a) => a.iter().for_each(|x| model_objects(x, out)),
        _ => {}
    }
}

#[test]
fn catalogue_covers_every_model() {
    let cases = models();
    let mut objects = Vec::new();
    for (_, m) in &cases {
        model_objects(&m.to_json(), &mut objects);
    }
    let terms: Vec<&str> = MODEL_CASES
        .iter()
        .flat_map(|s| s.split(" + "))
        .map(str::trim)
        .collect();
    let mut missing = Vec::new();
    for decl in CATALOG {
        let of_model: Vec<_> = objects.iter().filter(|o| o["model"] == decl.name).collect();
        if of_model.is_empty() {
            missing.push(format!("model {}", decl.name));
        }
        for alias in decl.aliases {
            if !terms
                .iter()
                .any(|t| t.starts_with(&format!("{}:", alias.name)))
            {
                missing.push(format!("alias {}", alias.name));
            }
        }
        // Every value of every choice parameter (distribution, shadowing, g1, variant, norm).
        for p in decl.params {
            if let ParamKind::Choice(choices) = p.kind {
                for c in choices {
                    if !of_model
                        .iter()
                        .any(|o| o.get(p.name) == Some(&Value::from(*c)))
                    {
                        missing.push(format!("{} {} = {c}", decl.name, p.name));
                    }
                }
            }
            if p.kind == ParamKind::Fresnel {
                for (ty, _, _) in FRESNEL_TYPES {
                    if !of_model.iter().any(|o| o["fresnel"]["type"] == *ty) {
                        missing.push(format!("{} fresnel type {ty}", decl.name));
                    }
                }
            }
        }
        // Anisotropic variants of every model that has them.
        if decl.isotropic != "always" && decl.name != "sum" {
            let aniso = cases.iter().any(|(_, m)| {
                m.name() == decl.name && !m.is_isotropic()
                    || matches!(m, Model::Sum(s) if s.terms.iter().any(|t| t.name() == decl.name && !t.is_isotropic()))
            });
            if !aniso {
                missing.push(format!("an anisotropic {}", decl.name));
            }
        }
    }
    for (metal, _, _) in METALS {
        if !terms
            .iter()
            .any(|t| t.contains(&format!("fresnel={metal}")))
        {
            missing.push(format!("metal {metal}"));
        }
    }
    assert!(
        missing.is_empty(),
        "MODEL_CASES lacks a case for: {}",
        missing.join("; ")
    );
    println!(
        "{} model cases, {} invalid-parameter cases",
        MODEL_CASES.len(),
        INVALID_CASES.len()
    );
}

// ---------------------------------------------------------------------------------------------
// The hard direction pairs.
// ---------------------------------------------------------------------------------------------

/// A unit direction with the given z (may be 0, tiny or negative) and azimuth.
fn dz(z: f64, phi: f64) -> Vec3 {
    let r = (1.0 - z * z).max(0.0).sqrt();
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

fn deg(theta: f64, phi: f64) -> Vec3 {
    Vec3::from_spherical(theta.to_radians(), phi)
}

/// The direction pairs of hard-cases.md, labelled. Pairs with a direction at or below the
/// horizon are marked: their value must be exactly 0.
fn hard_pairs() -> Vec<(String, Vec3, Vec3, bool)> {
    let mut p: Vec<(String, Vec3, Vec3, bool)> = Vec::new();
    let mut add = |label: String, wi: Vec3, wo: Vec3| {
        let below = !(wi.z > 0.0 && wo.z > 0.0);
        p.push((label, wi, wo, below));
    };
    let z = Vec3::Z;
    // Polar positions from the normal to the horizon, as (label, direction at φ = 0.3).
    let polar: Vec<(&str, Vec3)> = vec![
        ("tilt 1e-9 rad", Vec3::from_spherical(1e-9, 0.3)),
        ("tilt 1e-6 rad", Vec3::from_spherical(1e-6, 0.3)),
        ("tilt 1e-3 rad", Vec3::from_spherical(1e-3, 0.3)),
        ("30°", deg(30.0, 0.3)),
        ("60°", deg(60.0, 0.3)),
        ("89.99°", deg(89.99, 0.3)),
        ("z = 1e-4", dz(1e-4, 0.3)),
        ("z = 1e-12", dz(1e-12, 0.3)),
        ("z = 1e-160", dz(1e-160, 0.3)),
        ("z = 1e-300", dz(1e-300, 0.3)),
        ("z = 5e-324", dz(5e-324, 0.3)),
    ];
    add("both normal".into(), z, z);
    for (l, v) in &polar {
        add(format!("normal, {l}"), z, *v);
        add(format!("retro wi = wo at {l}"), *v, *v);
        add(format!("mirror at {l}"), *v, v.mirror());
    }
    // wi = −wo: the half vector is undefined (one of them is below the horizon).
    for (l, v) in polar.iter().step_by(2) {
        add(format!("wi = −wo at {l}"), *v, -*v);
    }
    // The horizon itself and just below.
    let horizon = Vec3::from_spherical(FRAC_PI_2, 0.7);
    add("wi on the horizon".into(), horizon, deg(40.0, 2.0));
    add(
        "both on the horizon, mirror".into(),
        horizon,
        horizon.mirror(),
    );
    add("wi on the horizon, wo normal".into(), horizon, z);
    add(
        "wi just below (z = −1e-12)".into(),
        dz(-1e-12, 1.0),
        deg(40.0, 2.0),
    );
    add(
        "wi straight down".into(),
        Vec3::new(0.0, 0.0, -1.0),
        deg(40.0, 2.0),
    );
    add(
        "both below, mirror".into(),
        dz(-0.5, 1.0),
        dz(-0.5, 1.0).mirror(),
    );
    add("wi below, retro".into(), dz(-1e-300, 1.0), dz(-1e-300, 1.0));
    // Grazing pairs.
    let g = deg(89.99, 0.0);
    add(
        "grazing, near mirror (φ off by 1e-6)".into(),
        g,
        deg(89.99, PI - 1e-6),
    );
    add("grazing, perpendicular".into(), g, deg(89.99, FRAC_PI_2));
    add(
        "grazing, near opposite (φ off by 1e-3)".into(),
        g,
        deg(89.99, 1e-3),
    );
    add(
        "z = 1e-300, near mirror".into(),
        dz(1e-300, 0.0),
        dz(1e-300, PI - 1e-3),
    );
    add(
        "z = 1e-300, perpendicular".into(),
        dz(1e-300, 0.0),
        dz(1e-300, FRAC_PI_2),
    );
    add(
        "z = 1e-300 with 45°".into(),
        dz(1e-300, 0.0),
        deg(45.0, 2.5),
    );
    add(
        "z = 1e-300 with z = 1e-12".into(),
        dz(1e-300, 0.0),
        dz(1e-12, 2.0),
    );
    add(
        "nearly opposite, 1e-8 above the horizon".into(),
        Vec3::new(1.0, 0.0, 1e-8).try_normalize().unwrap(),
        Vec3::new(-1.0, 1e-8, 1e-8).try_normalize().unwrap(),
    );
    // Exactly in-plane pairs (φd = 0 or π, the fold of an isotropic table) and the
    // anisotropic axes.
    add("in plane, same side".into(), deg(40.0, 0.0), deg(70.0, 0.0));
    add(
        "in plane, opposite sides".into(),
        deg(40.0, 0.0),
        deg(70.0, PI),
    );
    add(
        "in plane along y".into(),
        deg(40.0, FRAC_PI_2),
        deg(70.0, -FRAC_PI_2),
    );
    add("off plane".into(), deg(25.0, 0.4), deg(55.0, 2.9));
    // φ seams: 0 / 2π and −π / π.
    let wo = deg(30.0, PI / 3.0);
    for (l, phi) in [
        ("φi = 0", 0.0),
        ("φi = 2π", 2.0 * PI),
        ("φi = −1e-12", -1e-12),
        ("φi = π", PI),
        ("φi = −π", -PI),
    ] {
        add(format!("seam {l}"), deg(50.0, phi), wo);
    }
    // Near the pole φ is undefined: tiny tilts at different azimuths.
    for phi in [0.0, 1.0, 2.0, 4.0] {
        add(
            format!("near-pole wi at φ = {phi}"),
            Vec3::from_spherical(1e-9, phi),
            deg(50.0, 0.5),
        );
    }
    add(
        "near-pole mirror pair".into(),
        Vec3::from_spherical(1e-9, 0.0),
        Vec3::from_spherical(1e-9, PI),
    );
    add(
        "normal and a tilt of 1e-300 rad".into(),
        z,
        Vec3::from_spherical(1e-300, 1.0),
    );
    add(
        "tilts of 1e-300 rad, mirror".into(),
        Vec3::from_spherical(1e-300, 0.0),
        Vec3::from_spherical(1e-300, PI),
    );
    add(
        "subnormal x component".into(),
        Vec3::new(5e-324, 0.0, 1.0),
        deg(30.0, 1.0),
    );
    add("normal and straight down".into(), z, -z);
    // θh tiny but not 0 (φh barely defined): the mirror pair rotated by a tiny angle.
    for t in [1e-9, 1e-6, 1e-3] {
        add(
            format!("mirror at 45° off by {t} rad"),
            deg(45.0, 0.0),
            deg(45.0, PI + t),
        );
    }
    add(
        "retro along y at 45°".into(),
        deg(45.0, FRAC_PI_2),
        deg(45.0, FRAC_PI_2),
    );
    add(
        "z = 1e-12 and z = 1e-4, opposite φ".into(),
        dz(1e-12, 0.0),
        dz(1e-4, PI),
    );
    add(
        "z = 1e-4, perpendicular".into(),
        dz(1e-4, 0.0),
        dz(1e-4, FRAC_PI_2),
    );
    add(
        "z = 1e-160, near mirror".into(),
        dz(1e-160, 0.0),
        dz(1e-160, PI - 1e-6),
    );
    add(
        "wo on the horizon at wi's mirror".into(),
        deg(30.0, 0.0),
        Vec3::from_spherical(FRAC_PI_2, PI),
    );
    p
}

/// |a − b| relative to the larger magnitude (0 when both are 0).
fn rel(a: f64, b: f64) -> f64 {
    let m = a.abs().max(b.abs());
    if m == 0.0 { 0.0 } else { (a - b).abs() / m }
}

#[test]
fn every_model_at_every_hard_pair() {
    let pairs = hard_pairs();
    let mut failures = Vec::new();
    let mut worst = (0.0f64, String::new());
    let mut evaluated = 0usize;
    for (spec, m) in models() {
        if spec.starts_with("mirror") {
            // A delta has no pointwise value: refused with a message pointing elsewhere.
            let e = m.check_tabulable().unwrap_err().to_string();
            assert!(e.contains("Dirac delta"), "{spec}: {e}");
        }
        let reciprocal = m.is_reciprocal();
        assert!(
            reciprocal,
            "{spec}: models.md says every model is reciprocal"
        );
        for (label, wi, wo, below) in &pairs {
            // A panic (a debug assertion on NaN, say) is reported with its model and pair.
            let both = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                (eval(&m, *wi, *wo), eval(&m, *wo, *wi))
            }));
            let Ok((a, b)) = both else {
                failures.push(format!("{spec} [{label}]: panicked (see above)"));
                continue;
            };
            evaluated += 2;
            for (c, (x, y)) in a.iter().zip(&b).enumerate() {
                if !(x.is_finite() && *x >= 0.0) {
                    failures.push(format!("{spec} [{label}] ch {c}: f = {x}"));
                } else if *below && *x != 0.0 {
                    failures.push(format!("{spec} [{label}] ch {c}: below horizon f = {x}"));
                } else if reciprocal && rel(*x, *y) > 1e-12 {
                    failures.push(format!(
                        "{spec} [{label}] ch {c}: f(wi, wo) = {x:e} but f(wo, wi) = {y:e}"
                    ));
                }
                let r = rel(*x, *y);
                if r > worst.0 {
                    worst = (r, format!("{spec} [{label}]"));
                }
            }
        }
    }
    println!(
        "{} models × {} pairs: {evaluated} evaluations; worst reciprocity {:.1e} at {}",
        MODEL_CASES.len(),
        pairs.len(),
        worst.0,
        worst.1
    );
    assert!(
        failures.is_empty(),
        "{} failures:\n{}",
        failures.len(),
        failures[..failures.len().min(40)].join("\n")
    );
}

#[test]
fn models_are_continuous_across_phi_seams() {
    // The same direction written with φ = 0 and φ = 2π (or ±1e-12, or ±π) must give the same
    // value up to the rounding of sin/cos.
    let wo = deg(30.0, PI / 3.0);
    let mut failures = Vec::new();
    for (spec, m) in models() {
        for theta in [1e-9f64, 0.3, 1.2, 1.5706] {
            for (p, q) in [
                (0.0, 2.0 * PI),
                (-1e-12, 1e-12),
                (PI, -PI),
                (0.0, -2.0 * PI),
            ] {
                let a = eval(&m, Vec3::from_spherical(theta, p), wo);
                let b = eval(&m, Vec3::from_spherical(theta, q), wo);
                let (c, d) = (
                    eval(
                        &m,
                        wo.rotate_z(p),
                        Vec3::from_spherical(theta, 0.7).rotate_z(p),
                    ),
                    eval(
                        &m,
                        wo.rotate_z(q),
                        Vec3::from_spherical(theta, 0.7).rotate_z(q),
                    ),
                );
                for (x, y) in a.iter().zip(&b).chain(c.iter().zip(&d)) {
                    if rel(*x, *y) > 1e-6 {
                        failures.push(format!("{spec}: θ = {theta}, φ {p} vs {q}: {x:e} vs {y:e}"));
                    }
                }
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn index_matched_fresnel_is_zero_at_every_angle() {
    // IOR exactly 1 (hard-cases.md): F = 0 at every c > 0, also where c² and c⁴ underflow
    // (the conductor form gave 0/0 = NaN at c = 5e-324 and −0.17 below c ≈ 1e-77).
    for c in [1.0, 0.5, 1e-9, 1e-80, 1e-100, 1e-170, 1e-300, 5e-324] {
        assert_eq!(fresnel_dielectric(1.0, c), 0.0, "dielectric at c = {c}");
        assert_eq!(fresnel_conductor(1.0, 0.0, c), 0.0, "conductor at c = {c}");
        // Any other index tends to 1 at grazing, stays in [0, 1] and is finite.
        for (eta, k) in [(1.5, 0.0), (0.67, 0.0), (1e-6, 0.0), (1e6, 0.0)] {
            let f = fresnel_dielectric(eta, c);
            assert!((0.0..=1.0).contains(&f), "dielectric {eta} at c = {c}: {f}");
            let f = fresnel_conductor(eta, k, c);
            assert!(
                (0.0..=1.0).contains(&f),
                "conductor {eta}, {k} at c = {c}: {f}"
            );
        }
        for (eta, k) in [
            (0.143, 3.983),
            (1e-3, 1e6),
            (1e6, 1e6),
            (0.0, 0.0),
            (1.0, 1e-9),
        ] {
            let f = fresnel_conductor(eta, k, c);
            assert!(
                (0.0..=1.0).contains(&f),
                "conductor {eta}, {k} at c = {c}: {f}"
            );
        }
    }
}

#[test]
fn invalid_parameters_exit_2_naming_the_parameter() {
    let mut failures = Vec::new();
    for (spec, name) in INVALID_CASES {
        assert!(Model::parse(spec).is_err(), "{spec} parses");
        let out = Command::cargo_bin("brdfpack")
            .unwrap()
            .args(["eval", spec, "--wi", "0,0,1", "--wo", "0,0,1"])
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        let named = err
            .split(|c: char| !(c.is_alphanumeric() || c == '_'))
            .any(|w| w == *name);
        if out.status.code() != Some(2) || !out.stdout.is_empty() {
            failures.push(format!(
                "{spec}: exit {:?}, stdout {:?}",
                out.status.code(),
                String::from_utf8_lossy(&out.stdout)
            ));
        } else if !err.starts_with("brdfpack:") || !named {
            failures.push(format!("{spec}: message does not name {name}: {err}"));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

// ---------------------------------------------------------------------------------------------
// The eval CLI on non-unit, huge and non-finite vectors.
// ---------------------------------------------------------------------------------------------

#[test]
fn eval_normalizes_huge_and_tiny_vectors() {
    let spec = "ggx:alpha=0.3,fresnel=au";
    let m = parse(spec);
    // (vector as typed, the unit vector it means)
    let cases: [([f64; 3], [f64; 3]); 2] = [
        ([1e200, 0.0, 1e200], [3e-300, 0.0, 2e-300]),
        ([0.0, 0.0, 2.0], [0.0, 1e300, 1e300]),
    ];
    for (wi, wo) in cases {
        let text = |v: [f64; 3]| format!("{:e},{:e},{:e}", v[0], v[1], v[2]);
        let out = Command::cargo_bin("brdfpack")
            .unwrap()
            .args(["eval", spec, "--wi", &text(wi), "--wo", &text(wo)])
            .output()
            .unwrap();
        assert_eq!(
            out.status.code(),
            Some(0),
            "{wi:?} {wo:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let got: Vec<f64> = String::from_utf8(out.stdout)
            .unwrap()
            .split_whitespace()
            .map(|s| s.parse().unwrap())
            .collect();
        let unit = |v: [f64; 3]| {
            let s = v.iter().fold(0.0f64, |m, x| m.max(x.abs()));
            Vec3::new(v[0] / s, v[1] / s, v[2] / s)
                .try_normalize()
                .unwrap()
        };
        let want = eval(&m, unit(wi), unit(wo));
        assert_eq!(got.len(), want.len());
        for (g, w) in got.iter().zip(&want) {
            assert!(rel(*g, *w) <= 1e-12, "{wi:?} {wo:?}: {g} vs {w}");
        }
    }
    // The same through a stream, with NaN on the last line: rows before it, then exit 2.
    let out = Command::cargo_bin("brdfpack")
        .unwrap()
        .args(["eval", spec])
        .write_stdin("1e200 0 1e200 0 1e-200 1e-200\n0 0 0.5 0 0 2\nnan 0 1 0 0 1\n")
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let stdout = String::from_utf8(out.stdout).unwrap();
    assert_eq!(stdout.lines().count(), 2, "{stdout}");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("line 3") && err.contains("\"nan\""), "{err}");
}

// ---------------------------------------------------------------------------------------------
// Tables: every grid kind, every codec, every file format.
// ---------------------------------------------------------------------------------------------

/// Every grid kind and option, small enough for a debug-profile test.
const GRIDS: &[&str] = &[
    "spherical4:6x8x6x8",
    "spherical3:8x8x12",
    "halfdiff3:12x8x16,warp=sqrt/linear/linear,at=edge",
    "halfdiff3:8x8x12",
    "halfdiff4:6x8x6x8",
    "halfdiff4:6,at=edge",
    "spherical4:6,theta-max=80",
    "halfdiff3:8,theta-max=85",
];

/// Sources tabulated on every grid: an all-zero table, a GGX peak of ~1e9 next to black
/// cells, an anisotropic Ward, a rough HTSG, and a sum.
const TABLE_SOURCES: &[&str] = &[
    "lambert:albedo=0/0/0",
    "ggx:alpha=0.0005,fresnel=au",
    "ward:variant=duer,rho_s=1,alpha_x=0.01,alpha_y=0.5",
    "htsg:sigma0=1,tau=2",
    "lambert:albedo=0.2 + beckmann:alpha=0.001,g1=rational",
];

/// Every codec form: lossless ones must round-trip bit for bit, lossy ones within their
/// bound.
const CODECS: &[&str] = &[
    "zstd-f32",
    "lossless",
    "lossless:predict=ORDERS,space=integer,cross=off",
    "f16",
    "f16:curve=linear",
    "uniform:bits=12",
    "uniform:bits=8,curve=linear",
    "uniform:bits=10,curve=linear,colour=none",
    "dct:step=0.01",
    "dct:step=0.05,curve=linear",
    "dct:step=0.01,coding=zstd",
    "dct:step=0.02,deadzone=1.5,refine=2",
];

fn tab(src: &dyn Brdf, grid: &str) -> Table {
    let g = parse_grid_spec(grid).unwrap();
    let opts = TabulateOptions {
        allow_anisotropic: true,
        ..Default::default()
    };
    tabulate(src, &g, &opts).unwrap_or_else(|e| panic!("{} on {grid}: {e}", src.describe()))
}

/// A synthetic table of huge dynamic range: 8e10 peaks, 1e-30, zeros and 1e4 steps.
fn spiky_table(grid: &str) -> Table {
    let g = parse_grid_spec(grid).unwrap();
    let valid = g.geometric_mask();
    let values = [8e10f32, 0.0, 1e-30, 1e4, 1.0, 3e-7, 0.0];
    let data: Vec<f32> = (0..g.cells() * 3)
        .map(|i| values[(i * 7 + i / 5) % values.len()])
        .zip(0..)
        .map(|(v, i)| if valid[i / 3] { v } else { 0.0 })
        .collect();
    Table::new(
        g,
        Channels::default_for(3),
        Provenance::default(),
        data,
        valid,
    )
    .unwrap()
}

/// The largest magnitude of the table's valid components in the codec's transformed space.
fn peak_transformed(t: &Table, spec: &CodecSpec) -> f64 {
    let (CodecSpec::Dct { transform, .. }
    | CodecSpec::DctContext { transform, .. }
    | CodecSpec::Quantized { transform, .. }) = spec
    else {
        return 0.0;
    };
    let c = t.channels().len();
    let z = transform.forward_all(t.data(), c, t.grid(), t.valid());
    z.chunks_exact(c)
        .zip(t.valid())
        .filter(|(_, ok)| **ok)
        .flat_map(|(v, _)| v.iter())
        .fold(0.0f64, |m, v| m.max(v.abs()))
}

fn assert_table_sane(t: &Table, what: &str) {
    for (i, v) in t.data().iter().enumerate() {
        assert!(v.is_finite() && *v >= 0.0, "{what}: sample {i} = {v}");
    }
}

/// Checks a decoded table against its original under `codec` (lossless: bit for bit; lossy:
/// the codec's stated bound in its transformed space).
fn check_codec(orig: &Table, back: &Table, codec: &CodecSpec, what: &str) {
    assert_eq!(back.valid(), orig.valid(), "{what}: validity changed");
    let c = orig.channels().len();
    if codec.is_lossless() {
        for (i, (a, b)) in orig.data().iter().zip(back.data()).enumerate() {
            assert_eq!(a.to_bits(), b.to_bits(), "{what}: sample {i}: {a} → {b}");
        }
        return;
    }
    assert_table_sane(back, what);
    let (transform, bound): (_, Box<dyn Fn(usize, f64) -> f64>) = match codec {
        CodecSpec::Quantized {
            transform,
            quantize,
            ..
        } => match (quantize, codec.max_transformed_error()) {
            (_, Some(e)) => (transform, Box::new(move |_, _| e)),
            (q @ Quantizer::F16 { .. }, None) => {
                let q = q.clone();
                (
                    transform,
                    Box::new(move |k, z: f64| q.max_error(k, z.abs())),
                )
            }
            _ => unreachable!("uniform has a bound"),
        },
        CodecSpec::Dct { transform, .. } | CodecSpec::DctContext { transform, .. } => {
            (transform, Box::new(|_, _| f64::INFINITY))
        }
        _ => unreachable!("lossless handled above"),
    };
    let mut sq = 0.0;
    let mut n = 0usize;
    let mut z_max = 0.0f64;
    for (cell, &ok) in orig.valid().iter().enumerate() {
        if !ok {
            continue;
        }
        for k in 0..c {
            let a = transform.curve.forward(orig.data()[cell * c + k] as f64, k);
            let b = transform.curve.forward(back.data()[cell * c + k] as f64, k);
            // f32 storage of the decoded value adds a relative 2^-24 (and 1e-30 subnormals).
            let tol = bound(k, a) * (1.0 + 1e-9) + 1e-6 * a.abs().max(1.0);
            assert!(
                (a - b).abs() <= tol,
                "{what}: cell {cell} ch {k}: {a} vs {b} (bound {tol})"
            );
            sq += (a - b) * (a - b);
            n += 1;
            z_max = z_max.max(a.abs());
        }
    }
    if let CodecSpec::Dct { dct, .. } = codec {
        // DCT has no per-sample bound; its RMS error is ≈ step/√12 in the transformed space
        // (docs/compression.md). Invalid-cell filling and the box cut can add to that, so
        // allow 4× before calling it broken. The inverse transform runs in f32, so each
        // sample also carries rounding of order 2^-24 × the largest component (a linear
        // table with 1e9 peaks: ~60 in every cell); allow 2^-20 × that.
        let step = dct.step.iter().fold(0.0f64, |m, s| m.max(*s));
        let rms = (sq / n.max(1) as f64).sqrt();
        let limit = 4.0 * step / 12f64.sqrt() + 2f64.powi(-20) * z_max;
        assert!(rms <= limit, "{what}: DCT RMS {rms:e} > {limit:e}");
    }
}

#[test]
fn tables_on_every_grid_through_every_codec() {
    let (mut done, mut refused) = (0usize, 0usize);
    for grid in GRIDS {
        let mut tables: Vec<(String, Table)> = TABLE_SOURCES
            .iter()
            .map(|s| (s.to_string(), tab(&parse(s), grid)))
            .collect();
        tables.push(("spiky synthetic".into(), spiky_table(grid)));
        for (src, t) in &tables {
            assert_table_sane(t, &format!("{src} on {grid}"));
            for codec in CODECS {
                // One predictor order per grid axis.
                let orders = vec!["1"; t.grid().axes().len()].join(".");
                let codec = codec.replace("ORDERS", &orders);
                let what = format!("{src} on {grid} via {codec}");
                let spec = CodecRequest::parse(&codec)
                    .unwrap()
                    .resolve(t)
                    .unwrap_or_else(|e| panic!("{what}: resolve: {e}"));
                let encoded = io::encode_table(t, &OutputFormat::Native(spec.clone()));
                if let CodecSpec::Dct { dct, .. } | CodecSpec::DctContext { dct, .. } = &spec {
                    // An orthonormal DCT coefficient is at most √cells × the largest value:
                    // below 2^30 steps the encoder must succeed, far above it (linear curve,
                    // 8e10 peaks) it must refuse rather than clamp the codes.
                    let z_max = peak_transformed(t, &spec);
                    let bound = (t.grid().cells() as f64).sqrt() * z_max / dct.step[0];
                    if bound > 2f64.powi(30) * 1e3 {
                        let e = encoded.expect_err(&what).to_string();
                        assert!(e.contains("step"), "{what}: {e}");
                        refused += 1;
                        continue;
                    }
                    assert!(
                        encoded.is_ok() || bound > 2f64.powi(30),
                        "{what}: {}",
                        encoded.unwrap_err()
                    );
                }
                let Ok(bytes) = encoded else {
                    panic!("{what}: encode: {}", encoded.unwrap_err());
                };
                let back = io::decode_table(&bytes, Path::new("x.bpk"))
                    .unwrap_or_else(|e| panic!("{what}: decode: {e}"));
                check_codec(t, &back, &spec, &what);
                done += 1;
            }
        }
    }
    println!("{done} table × codec round trips; {refused} linear DCT encodes refused (range)");
    assert!(
        refused > 0 && refused < done / 10,
        "the range check was not exercised"
    );
}

#[test]
fn exr_round_trips_hard_tables() {
    for grid in [
        "halfdiff3:12x8x16,warp=sqrt/linear/linear,at=edge",
        "spherical4:6x8x6x8",
    ] {
        let mut tables: Vec<(String, Table)> = TABLE_SOURCES
            .iter()
            .map(|s| (s.to_string(), tab(&parse(s), grid)))
            .collect();
        tables.push(("spiky synthetic".into(), spiky_table(grid)));
        for (src, t) in &tables {
            for (sample_type, compression) in [
                (ExrSampleType::F32, ExrCompression::Zip),
                (ExrSampleType::F32, ExrCompression::Piz),
                (ExrSampleType::F32, ExrCompression::Pxr24),
                (ExrSampleType::F16, ExrCompression::Zip),
            ] {
                let what = format!("{src} on {grid} as EXR {sample_type:?}/{compression:?}");
                let opts = ExrOptions {
                    sample_type,
                    compression,
                };
                let bytes = io::encode_table(t, &OutputFormat::Exr(opts))
                    .unwrap_or_else(|e| panic!("{what}: {e}"));
                let back = io::decode_table(&bytes, Path::new("x.exr"))
                    .unwrap_or_else(|e| panic!("{what}: {e}"));
                assert_table_sane(&back, &what);
                assert_eq!(back.valid(), t.valid(), "{what}");
                // f16: 11 significant bits (rel 2^-11), values below its normal range lose
                // relative precision (abs 2^-25 × the file's power-of-two scale); PXR24:
                // 24-bit floats (rel 2^-15).
                let (r, a) = match (opts.is_lossless(), sample_type) {
                    (true, _) => (0.0, 0.0),
                    (false, ExrSampleType::F16) => (2f64.powi(-11), 6e-8),
                    (false, ExrSampleType::F32) => (2f64.powi(-15), 1e-38),
                };
                let peak = t.data().iter().fold(0.0f32, |m, v| m.max(*v)) as f64;
                // The scale for values above 65504 multiplies the absolute floor too.
                let a = a * (peak / 65504.0).max(1.0) * 2.0;
                for (i, (x, y)) in t.data().iter().zip(back.data()).enumerate() {
                    let (x, y) = (*x as f64, *y as f64);
                    assert!(
                        (x - y).abs() <= r * x.abs() + a,
                        "{what}: sample {i}: {x} → {y}"
                    );
                }
            }
        }
    }
}

#[test]
fn merl_round_trips_and_sentinels() {
    let grid = "halfdiff3:12x8x16,warp=sqrt/linear/linear,at=edge";
    let mut tables: Vec<(String, Table)> = TABLE_SOURCES
        .iter()
        .filter(|s| parse(s).is_isotropic() || s.starts_with("ward"))
        .map(|s| (s.to_string(), tab(&parse(s), grid)))
        .collect();
    tables.push(("spiky synthetic".into(), spiky_table(grid)));
    for (src, t) in &tables {
        if t.channels().len() != 3 {
            continue;
        }
        let bytes = io::encode_table(t, &OutputFormat::Merl).unwrap();
        // Below-horizon cells are written as the raw sentinel −1 (MERL convention).
        let n = t.grid().cells();
        let raw = |c: usize, cell: usize| {
            let at = 12 + 8 * (c * n + cell);
            f64::from_le_bytes(bytes[at..at + 8].try_into().unwrap())
        };
        for (cell, &ok) in t.valid().iter().enumerate() {
            for c in 0..3 {
                let r = raw(c, cell);
                if ok {
                    assert!(r >= 0.0 && r.is_finite(), "{src}: cell {cell}: raw {r}");
                } else {
                    assert_eq!(r, -1.0, "{src}: invalid cell {cell}");
                }
            }
        }
        let back = io::decode_table(&bytes, Path::new("x.binary")).unwrap();
        assert_eq!(back.valid(), t.valid(), "{src}");
        for (i, (x, y)) in t.data().iter().zip(back.data()).enumerate() {
            // Stored as f64 raw = value / scale, read back as (raw × scale) as f32: at most
            // one f32 rounding.
            assert!(
                ((*x as f64) - (*y as f64)).abs() <= (*x as f64).abs() * 2f64.powi(-23),
                "{src}: sample {i}: {x} → {y}"
            );
        }
        let lookup = MerlLookup::from_table(&back).unwrap();
        for (label, wi, wo, below) in hard_pairs() {
            for v in eval(&lookup, wi, wo) {
                assert!(
                    v.is_finite() && v >= 0.0,
                    "{src} MERL lookup [{label}]: {v}"
                );
                if below {
                    assert_eq!(v, 0.0, "{src} MERL lookup [{label}]");
                }
            }
        }
    }
}

/// Table lookups (linear and nearest) at every hard pair, and across the φ seams.
#[test]
fn table_lookups_at_hard_pairs_and_seams() {
    let pairs = hard_pairs();
    for grid in GRIDS {
        for src in TABLE_SOURCES {
            let t = tab(&parse(src), grid);
            for interp in [Interp::Linear, Interp::Nearest] {
                let mut out = vec![0.0; t.channels().len()];
                for (label, wi, wo, below) in &pairs {
                    t.eval_into(*wi, *wo, interp, &mut out);
                    for v in &out {
                        assert!(
                            v.is_finite() && *v >= 0.0,
                            "{src} on {grid} {interp:?} [{label}]: {v}"
                        );
                        if *below {
                            assert_eq!(*v, 0.0, "{src} on {grid} {interp:?} [{label}]");
                        }
                    }
                }
            }
            // Linear interpolation is continuous across the φ wrap-around (0 / 2π) and the
            // φd fold: values at φ = ±1e-9 around each seam agree to 1e-6 of the table's peak.
            let peak = t.data().iter().fold(0.0f32, |m, v| m.max(*v)) as f64;
            let wo = deg(35.0, 0.0);
            let mut a = vec![0.0; t.channels().len()];
            let mut b = a.clone();
            for seam in [0.0, PI, FRAC_PI_2] {
                for theta in [20.0, 60.0] {
                    let (p, q) = (seam - 1e-9, seam + 1e-9);
                    t.eval_into(deg(theta, p), wo, Interp::Linear, &mut a);
                    t.eval_into(deg(theta, q), wo, Interp::Linear, &mut b);
                    // Both directions rotated together (the φh seam of halfdiff4, φi of
                    // spherical4).
                    let (mut c, mut d) = (a.clone(), b.clone());
                    t.eval_into(deg(theta, p), wo.rotate_z(p), Interp::Linear, &mut c);
                    t.eval_into(deg(theta, q), wo.rotate_z(q), Interp::Linear, &mut d);
                    for (x, y) in a.iter().zip(&b).chain(c.iter().zip(&d)) {
                        assert!(
                            (x - y).abs() <= 1e-6 * peak,
                            "{src} on {grid}: seam φ = {seam}, θ = {theta}: {x} vs {y}"
                        );
                    }
                }
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Measured data from ../shared.
// ---------------------------------------------------------------------------------------------

#[test]
fn measured_rgl_files_at_hard_pairs() {
    let Some(dir) = common::shared_dir().map(|d| d.join("data/rgl")) else {
        println!("skipped: ../shared not found (set BRDFPACK_SHARED to run this test)");
        return;
    };
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .map(|r| r.filter_map(|e| e.ok().map(|e| e.path())).collect())
        .unwrap_or_default();
    files.retain(|p| p.extension().is_some_and(|e| e == "bsdf"));
    files.sort();
    if files.is_empty() {
        println!("skipped: no .bsdf files in {}", dir.display());
        return;
    }
    let pairs = hard_pairs();
    for f in &files {
        let raw = RglBsdf::open(f).unwrap_or_else(|e| panic!("{}: {e}", f.display()));
        let clamped = raw.clone().with_clamp_negative(true);
        for (label, wi, wo, below) in &pairs {
            let a = eval(&raw, *wi, *wo);
            let b = eval(&clamped, *wi, *wo);
            for (x, y) in a.iter().zip(&b) {
                // The files hold small negative fitted values (data/README.md), passed
                // through unless clamping is asked for.
                assert!(x.is_finite(), "{} [{label}]: {x}", f.display());
                assert!(
                    y.is_finite() && *y >= 0.0,
                    "{} clamped [{label}]: {y}",
                    f.display()
                );
                assert_eq!(*y, x.max(0.0), "{} [{label}]", f.display());
                if *below {
                    assert_eq!(*x, 0.0, "{} [{label}]", f.display());
                }
            }
        }
    }
    println!("{} RGL files × {} pairs", files.len(), pairs.len());
}

#[test]
fn measured_merl_files_at_hard_pairs() {
    let Some(dir) = common::shared_dir().map(|d| d.join("data/merl")) else {
        println!("skipped: ../shared not found (set BRDFPACK_SHARED to run this test)");
        return;
    };
    let pairs = hard_pairs();
    let mut n = 0;
    for name in ["gold-metallic-paint", "white-diffuse-bball"] {
        let path = dir.join(format!("{name}.binary"));
        if !path.is_file() {
            println!("skipped: {} not found", path.display());
            continue;
        }
        n += 1;
        let t = io::read_table(&path).unwrap();
        // The −1 sentinels mark invalid cells; no valid cell is negative.
        let invalid = t.valid().iter().filter(|v| !**v).count();
        assert!(invalid > 0, "{name}: the file has −1 sentinels");
        for (cell, &ok) in t.valid().iter().enumerate() {
            if ok {
                assert!(
                    t.cell(cell).iter().all(|v| v.is_finite() && *v >= 0.0),
                    "{name}"
                );
            }
        }
        let lookup = MerlLookup::from_table(&t).unwrap();
        let mut out = vec![0.0; 3];
        for (label, wi, wo, below) in &pairs {
            for interp in [Interp::Linear, Interp::Nearest] {
                t.eval_into(*wi, *wo, interp, &mut out);
                for v in &out {
                    assert!(
                        v.is_finite() && *v >= 0.0,
                        "{name} {interp:?} [{label}]: {v}"
                    );
                    if *below {
                        assert_eq!(*v, 0.0, "{name} {interp:?} [{label}]");
                    }
                }
            }
            for v in eval(&lookup, *wi, *wo) {
                assert!(v.is_finite() && v >= 0.0, "{name} MERL rule [{label}]: {v}");
                if *below {
                    assert_eq!(v, 0.0, "{name} MERL rule [{label}]");
                }
            }
        }
    }
    if n == 0 {
        println!("skipped: no MERL files in {}", dir.display());
    }
}

// ---------------------------------------------------------------------------------------------
// Property test over random parameters (extremes included) and directions.
// ---------------------------------------------------------------------------------------------

/// A roughness from 1e-6 to 10, with the ends and 1 as likely picks.
fn roughness() -> impl Strategy<Value = f64> {
    prop_oneof![
        Just(1e-6),
        Just(1e-4),
        Just(1.0),
        Just(10.0),
        (-6.0f64..1.0).prop_map(|e| 10f64.powf(e)),
    ]
}

fn unit_interval() -> impl Strategy<Value = f64> {
    prop_oneof![Just(0.0), Just(1.0), 0.0f64..=1.0]
}

fn exponent() -> impl Strategy<Value = f64> {
    prop_oneof![
        Just(0.0),
        Just(1e6),
        (-3.0f64..6.0).prop_map(|e| 10f64.powf(e))
    ]
}

fn ior() -> impl Strategy<Value = f64> {
    prop_oneof![
        Just(1.0),
        Just(1e-6),
        Just(1e6),
        (-6.0f64..6.0).prop_map(|e| 10f64.powf(e))
    ]
}

fn fresnel() -> impl Strategy<Value = String> {
    prop_oneof![
        Just("none".to_string()),
        unit_interval().prop_map(|f| format!("schlick,f0={f}")),
        ior().prop_map(|i| format!("dielectric,ior={i}")),
        (
            ior(),
            prop_oneof![Just(0.0), (-6.0f64..6.0).prop_map(|e| 10f64.powf(e))]
        )
            .prop_map(|(e, k)| format!("conductor,eta={e},k={k}")),
        prop::sample::select(vec!["au", "cu", "ag", "al"]).prop_map(str::to_string),
    ]
}

fn model_spec() -> impl Strategy<Value = String> {
    prop_oneof![
        unit_interval().prop_map(|a| format!("lambert:albedo={a}")),
        (unit_interval(), exponent(), prop::bool::ANY).prop_map(|(a, n, e)| format!(
            "phong:albedo={a},exponent={n},norm={}",
            if e { "energy" } else { "none" }
        )),
        (unit_interval(), exponent())
            .prop_map(|(a, n)| format!("blinn-phong:albedo={a},exponent={n}")),
        (roughness(), fresnel()).prop_map(|(m, f)| format!("torrance-sparrow:m={m},fresnel={f}")),
        (
            prop::bool::ANY,
            roughness(),
            roughness(),
            prop::sample::select(vec!["smith-correlated", "smith-separable", "v-cavity"]),
            prop::bool::ANY,
            fresnel()
        )
            .prop_map(|(ggx, ax, ay, sh, rational, f)| format!(
                "{}:alpha_x={ax},alpha_y={ay},shadowing={sh}{},fresnel={f}",
                if ggx { "ggx" } else { "beckmann" },
                if !ggx && rational { ",g1=rational" } else { "" }
            )),
        (
            prop::sample::select(vec!["ward", "duer", "balanced"]),
            unit_interval(),
            unit_interval(),
            roughness(),
            roughness()
        )
            .prop_map(|(v, s, d, ax, ay)| format!(
                "ward:variant={v},rho_s={s},rho_d={d},alpha_x={ax},alpha_y={ay}"
            )),
        (unit_interval(), 0.0f64..=FRAC_PI_2)
            .prop_map(|(a, s)| format!("oren-nayar:albedo={a},sigma={s}")),
        (unit_interval(), unit_interval(), exponent(), exponent())
            .prop_map(|(s, d, u, v)| format!("ashikhmin-shirley:rs={s},rd={d},nu={u},nv={v}")),
        (
            unit_interval(),
            -2.0f64..2.0,
            -2.0f64..2.0,
            exponent(),
            prop::bool::ANY
        )
            .prop_map(|(d, cxy, cz, n, ngan)| format!(
                "lafortune:diffuse={d},norm={},lobe={cxy}:{cxy}:{cz}:{n}",
                if ngan { "ngan" } else { "none" }
            )),
        (
            prop_oneof![Just(1e-3), Just(3.0), 0.01f64..1.0],
            prop_oneof![Just(0.1), Just(20.0), 0.5f64..5.0],
            ior(),
            prop_oneof![Just(0.0), 0.0f64..5.0]
        )
            .prop_map(|(s, t, e, k)| format!("htsg:sigma0={s},tau={t},eta_re={e},eta_im={k}")),
    ]
}

fn direction() -> impl Strategy<Value = Vec3> {
    let z = prop_oneof![
        3 => 0.0f64..=1.0,
        1 => prop::sample::select(vec![0.0, 1.0, 5e-324, 1e-300, 1e-160, 1e-12, 1e-4, -1e-12]),
        1 => (1e-9f64..1e-3).prop_map(f64::cos),
    ];
    let phi = prop_oneof![
        3 => 0.0..(2.0 * PI),
        1 => prop::sample::select(vec![0.0, PI, FRAC_PI_2, 2.0 * PI, -PI]),
    ];
    (z, phi).prop_map(|(z, p)| dz(z, p))
}

fn pair() -> impl Strategy<Value = (Vec3, Vec3)> {
    prop_oneof![
        3 => (direction(), direction()),
        1 => direction().prop_map(|v| (v, v)),
        1 => direction().prop_map(|v| (v, v.mirror())),
        1 => direction().prop_map(|v| (v, -v)),
        1 => direction().prop_map(|v| (Vec3::Z, v)),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(1024))]

    #[test]
    fn random_models_are_finite_nonnegative_and_reciprocal(
        spec in model_spec(),
        (wi, wo) in pair(),
    ) {
        let m = Model::parse(&spec).map_err(|e| TestCaseError::fail(format!("{spec}: {e}")))?;
        let a = eval(&m, wi, wo);
        let b = eval(&m, wo, wi);
        for (x, y) in a.iter().zip(&b) {
            prop_assert!(x.is_finite() && *x >= 0.0, "{} at {:?}, {:?}: {}", spec, wi, wo, x);
            if !(wi.z > 0.0 && wo.z > 0.0) {
                prop_assert_eq!(*x, 0.0, "{} below the horizon", spec);
            }
            if m.is_reciprocal() {
                prop_assert!(rel(*x, *y) <= 1e-12, "{} at {:?}, {:?}: {:e} vs {:e}", spec, wi, wo, x, y);
            }
        }
    }
}
