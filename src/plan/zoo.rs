//! The material zoo: generated materials that stress the encoder (dynamic range from ~10 to
//! ~1e8, tiny-α peaks, dark bodies, retro-reflection, grazing Fresnel, sums of lobes,
//! anisotropy), and the acceptance run of a budget over them (`brdfpack bench --zoo`,
//! docs/compression.md).
//!
//! The families are spanned by parameters, not picked to flatter one file: every
//! combination of body albedo × lobe roughness for the conductor family, every roughness for
//! the dielectric family, and so on.

/// A zoo material: a short name and a model spec (compact or JSON).
#[derive(Clone, Debug)]
pub struct ZooMaterial {
    pub name: String,
    pub spec: String,
}

/// The generated materials (31).
pub fn materials() -> Vec<ZooMaterial> {
    let mut out = Vec::new();
    let mut add = |name: String, spec: String| out.push(ZooMaterial { name, spec });
    // Conductor peak over a diffuse body: body albedo × roughness spans dynamic ranges from
    // ~10 (rough, bright body) to ~1e8 (α 5e-4 over a 0.002 body).
    for body in [0.5, 0.05, 0.002] {
        for alpha in [0.3, 0.1, 0.03, 0.01] {
            add(
                format!("gold-a{alpha}-body{body}"),
                format!("lambert:albedo={body}+ggx:alpha={alpha},fresnel=au"),
            );
        }
    }
    // Tiny-α peaks.
    for alpha in [0.002, 0.0005] {
        add(
            format!("silver-a{alpha}"),
            format!("lambert:albedo=0.01+ggx:alpha={alpha},fresnel=ag"),
        );
    }
    // Dielectric coat: grazing Fresnel over a coloured body.
    for alpha in [0.4, 0.15, 0.05] {
        add(
            format!("plastic-a{alpha}"),
            format!("lambert:albedo=0.6/0.2/0.05+ggx:alpha={alpha},fresnel=dielectric,ior=1.5"),
        );
    }
    // Beckmann copper, Torrance–Sparrow, Phong and Blinn–Phong.
    add(
        "copper-beckmann-0.2".into(),
        "beckmann:alpha=0.2,fresnel=cu".into(),
    );
    add(
        "torrance-sparrow-0.1".into(),
        "lambert:albedo=0.1+torrance-sparrow:m=0.1".into(),
    );
    add(
        "phong-500".into(),
        "lambert:albedo=0.3+phong:albedo=0.6,exponent=500".into(),
    );
    add(
        "blinn-phong-50".into(),
        "blinn-phong:albedo=0.8,exponent=50".into(),
    );
    // Dark bodies.
    add("dark-lambert".into(), "lambert:albedo=0.002".into());
    add(
        "dark-glossy".into(),
        "lambert:albedo=0.002+ggx:alpha=0.2,fresnel=dielectric,ior=1.5".into(),
    );
    // Retro-reflection: rough diffuse and a Lafortune retro lobe.
    add(
        "oren-nayar-1.0".into(),
        "oren-nayar:albedo=0.7,sigma=1.0".into(),
    );
    add(
        "retro-lafortune".into(),
        r#"{"model":"lafortune","diffuse":0.05,"lobes":[{"cx":0.9,"cy":0.9,"cz":0.9,"n":30}]}"#
            .into(),
    );
    add(
        "retro-plus-specular".into(),
        r#"{"model":"lafortune","diffuse":0.1,"lobes":[{"cx":0.8,"cy":0.8,"cz":0.8,"n":10},{"cx":-1,"cy":-1,"cz":1,"n":200}]}"#
            .into(),
    );
    // Sums of lobes.
    add(
        "two-lobes".into(),
        "lambert:albedo=0.2+ggx:alpha=0.05,fresnel=au+ggx:alpha=0.4,fresnel=al".into(),
    );
    add(
        "clearcoat".into(),
        "lambert:albedo=0.3/0.05/0.02+ggx:alpha=0.25,fresnel=cu+ggx:alpha=0.02,fresnel=dielectric,ior=1.5".into(),
    );
    // Anisotropy.
    add("ward-aniso".into(), "ward:alpha_x=0.1,alpha_y=0.3".into());
    add(
        "ggx-aniso".into(),
        "ggx:alpha_x=0.05,alpha_y=0.3,fresnel=au".into(),
    );
    add("ashikhmin-shirley".into(), "ashikhmin-shirley".into());
    out
}

/// `n` materials drawn from seeded families that span the zoo's hard cases, for acceptance
/// runs on materials no one picked (`bench --zoo --zoo-random N`). Each parameter is drawn
/// over its family's whole range, log-uniformly where it spans decades (roughness, body
/// albedo, exponents): a diffuse body under a conductor or dielectric peak (α 5e-4 … 0.6,
/// GGX or Beckmann, body albedo 1e-3 … 0.8 per channel), a bare conductor peak (α 1e-3 …
/// 0.1: no body, the widest dynamic range), two GGX lobes, rough diffuse under a Phong lobe,
/// Blinn–Phong over a body, Torrance–Sparrow over a body, and anisotropic GGX or Ward
/// (αx, αy 0.02 … 0.5). Names carry the seed and index, so a row can be made again alone.
pub fn random_materials(n: usize, seed: u64) -> Vec<ZooMaterial> {
    struct Draw(crate::math::SplitMix64);
    impl Draw {
        fn log_uniform(&mut self, lo: f64, hi: f64) -> f64 {
            (lo.ln() + self.0.next_f64() * (hi / lo).ln()).exp()
        }
        fn pick(&mut self, m: usize) -> usize {
            ((self.0.next_f64() * m as f64) as usize).min(m - 1)
        }
    }
    let mut d = Draw(crate::math::SplitMix64::new(seed));
    let mut out = Vec::with_capacity(n);
    for k in 0..n {
        let fresnel = |which: usize, x: f64| match which {
            0 => "fresnel=au".to_string(),
            1 => "fresnel=ag".to_string(),
            2 => "fresnel=cu".to_string(),
            3 => "fresnel=al".to_string(),
            4 => format!("fresnel=dielectric,ior={:.3}", 1.3 + 1.1 * x),
            _ => format!("fresnel=schlick,f0={:.3}", 0.02 + 0.88 * x),
        };
        let family = d.pick(8);
        let (tag, spec) = match family {
            0 | 1 => {
                let body: Vec<String> = (0..3)
                    .map(|_| format!("{:.4}", d.log_uniform(1e-3, 0.8)))
                    .collect();
                let alpha = d.log_uniform(5e-4, 0.6);
                let lobe = if family == 0 { "ggx" } else { "beckmann" };
                let (f, x) = (d.pick(6), d.log_uniform(1.0, 2.0) - 1.0);
                (
                    "body-peak",
                    format!(
                        "lambert:albedo={}+{lobe}:alpha={alpha:.5},{}",
                        body.join("/"),
                        fresnel(f, x)
                    ),
                )
            }
            2 => {
                let alpha = d.log_uniform(1e-3, 0.1);
                let f = d.pick(4);
                (
                    "bare-peak",
                    format!("ggx:alpha={alpha:.5},{}", fresnel(f, 0.0)),
                )
            }
            3 => {
                let (a1, a2) = (d.log_uniform(5e-3, 0.1), d.log_uniform(0.1, 0.7));
                let (f1, f2) = (d.pick(6), d.pick(6));
                let (x1, x2) = (d.log_uniform(1.0, 2.0) - 1.0, d.log_uniform(1.0, 2.0) - 1.0);
                (
                    "two-lobes",
                    format!(
                        "ggx:alpha={a1:.5},{}+ggx:alpha={a2:.5},{}",
                        fresnel(f1, x1),
                        fresnel(f2, x2)
                    ),
                )
            }
            4 => {
                let body = d.log_uniform(1e-3, 0.8);
                let sigma = 0.8 * d.log_uniform(1.0, 2.0) - 0.8;
                let (n, a) = (d.log_uniform(2.0, 800.0), d.log_uniform(0.05, 0.9));
                (
                    "rough-phong",
                    format!(
                        "oren-nayar:albedo={body:.4},sigma={sigma:.3}+phong:exponent={n:.2},albedo={a:.3}"
                    ),
                )
            }
            5 => {
                let (n, a, body) = (
                    d.log_uniform(2.0, 3000.0),
                    d.log_uniform(0.1, 0.9),
                    d.log_uniform(1e-3, 0.8),
                );
                (
                    "blinn-phong",
                    format!("blinn-phong:exponent={n:.2},albedo={a:.3}+lambert:albedo={body:.4}"),
                )
            }
            6 => {
                let (m, body) = (d.log_uniform(0.02, 0.5), d.log_uniform(1e-3, 0.8));
                let (f, x) = (d.pick(6), d.log_uniform(1.0, 2.0) - 1.0);
                (
                    "torrance-sparrow",
                    format!(
                        "torrance-sparrow:m={m:.4},{}+lambert:albedo={body:.4}",
                        fresnel(f, x)
                    ),
                )
            }
            _ => {
                let (ax, ay) = (d.log_uniform(0.02, 0.5), d.log_uniform(0.02, 0.5));
                if d.pick(2) == 0 {
                    let f = d.pick(4);
                    (
                        "aniso-ggx",
                        format!("ggx:alpha_x={ax:.4},alpha_y={ay:.4},{}", fresnel(f, 0.0)),
                    )
                } else {
                    (
                        "aniso-ward",
                        format!("ward:alpha_x={ax:.4},alpha_y={ay:.4}"),
                    )
                }
            }
        };
        out.push(ZooMaterial {
            name: format!("random{seed}-{k}-{tag}"),
            spec,
        });
    }
    out
}

use super::budget::Budget;
use super::pack::{PackInput, PackSettings, plan};
use super::rate::Effort;
use crate::Result;
use crate::check::{SampleSet, check_set};
use crate::io::native;
use crate::table::{Interp, InterpolatedTable};
use serde::Serialize;
use std::time::Instant;

/// One material × budget of the acceptance run.
#[derive(Clone, Debug, Serialize)]
pub struct ZooRow {
    pub material: String,
    /// The model spec or file the material is (set by the caller; empty when not).
    #[serde(skip_serializing_if = "String::is_empty")]
    pub spec: String,
    pub budget: String,
    pub grid: String,
    /// Whole native file, header included.
    pub bytes: usize,
    pub plan_s: f64,
    /// Per bound: the largest value over the verification seeds.
    pub worst: Vec<(String, f64)>,
    pub seeds: usize,
    pub pairs: usize,
    /// Every seed within every bound.
    pub holds: bool,
    /// Set when no file could be planned (the message).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

/// The source of a zoo row: `spec` opened (a model spec or a file), or with `sampled` an
/// isotropic reciprocal model's table on the MERL grid, as a MERL-format file of it would be
/// read (cut at the horizon, linear interpolation): the planner then keeps that grid and the
/// budget is against the table. True with the source when it is such a table.
pub fn zoo_source(spec: &str, sampled: bool) -> Result<(Box<dyn crate::brdf::Brdf>, bool)> {
    let src = crate::source::open_brdf(spec)?;
    if !(sampled && !src.is_sampled() && src.is_isotropic() && src.is_reciprocal()) {
        return Ok((src, false));
    }
    let grid = crate::grid::parse_grid_spec("merl")?;
    let table = crate::tabulate::tabulate(src.as_ref(), &grid, &Default::default())?;
    let table = InterpolatedTable {
        table,
        interp: Interp::Linear,
    };
    Ok((Box::new(table), true))
}

/// Packs `src` within `budget` at `effort` on its default grid, and measures the written
/// file against the source on `seeds` independent uniform sets of `pairs` pairs (seeds
/// 1000 + k, none of them the planner's).
#[allow(clippy::too_many_arguments)]
pub fn run_one(
    name: &str,
    src: &dyn crate::brdf::Brdf,
    budget_name: &str,
    budget: &Budget,
    effort: Effort,
    seeds: usize,
    pairs: usize,
) -> Result<ZooRow> {
    let settings = PackSettings {
        budget: budget.clone(),
        effort,
        check_samples: 65_536,
        check_seed: 1,
    };
    let t = Instant::now();
    // An RGL file is packed in its own parameterization, as `pack` packs it.
    let rgl = src
        .as_any()
        .and_then(|a| a.downcast_ref::<crate::io::rgl::RglBsdf>())
        .filter(|r| super::rgl::unsupported(r).is_none());
    let planned: Result<(String, Vec<u8>, Box<dyn crate::brdf::Brdf>)> = match rgl {
        Some(r) => {
            let provenance = crate::table::Provenance {
                source: crate::brdf::Brdf::describe(r),
                tool: crate::TOOL_VERSION.to_string(),
                notes: Vec::new(),
            };
            super::rgl::plan_rgl(r, &settings, false, &provenance, &|_| {}).and_then(|p| {
                let back = crate::io::rgl::RglBsdf::from_bytes(&p.bytes, "zoo.bpk")?;
                let form = format!(
                    "{} (VNDF {})",
                    crate::io::rgl::packed::FORMAT,
                    p.options.vndf.name()
                );
                Ok((form, p.bytes, Box::new(back) as Box<dyn crate::brdf::Brdf>))
            })
        }
        None => plan(
            PackInput::Source {
                source: src,
                grid: None,
                options: Default::default(),
            },
            &settings,
            &|_| {},
        )
        .and_then(|planned| {
            let bytes = native::to_bytes_with_payload(
                &planned.table,
                &planned.encoded.spec,
                &planned.encoded.payload,
            )?;
            let back = native::from_bytes(&bytes, std::path::Path::new("zoo.bpk"))?;
            let cand = InterpolatedTable {
                table: back,
                interp: Interp::Linear,
            };
            Ok((
                planned.grid,
                bytes,
                Box::new(cand) as Box<dyn crate::brdf::Brdf>,
            ))
        }),
    };
    let plan_s = t.elapsed().as_secs_f64();
    let row = |grid: String, bytes, worst, holds, error| ZooRow {
        material: name.to_string(),
        spec: String::new(),
        budget: budget_name.to_string(),
        grid,
        bytes,
        plan_s,
        worst,
        seeds,
        pairs,
        holds,
        error,
    };
    let (grid, bytes, cand) = match planned {
        Ok(p) => p,
        Err(crate::Error::Failure(msg)) => {
            return Ok(row(String::new(), 0, Vec::new(), false, Some(msg)));
        }
        Err(e) => return Err(e),
    };
    let mut worst: Vec<(String, f64)> = budget
        .bounds
        .iter()
        .map(|(k, _)| (k.clone(), 0.0))
        .collect();
    let mut holds = true;
    for k in 0..seeds {
        let r = check_set(
            src,
            cand.as_ref(),
            &SampleSet::uniform(pairs, 1000 + k as u64),
        )?;
        holds &= budget.met_by(&r.combined);
        for (name, w) in worst.iter_mut() {
            *w = w.max(r.combined.get(name).unwrap_or(f64::INFINITY));
        }
    }
    Ok(row(grid, bytes.len(), worst, holds, None))
}

/// The Markdown table of a run.
pub fn to_markdown(rows: &[ZooRow]) -> String {
    use std::fmt::Write;
    let mut s = String::from(
        "| material | budget | grid | bytes | plan s | worst over seeds | holds |\n|---|---|---|---:|---:|---|---|\n",
    );
    for r in rows {
        let worst = match &r.error {
            Some(e) => e.clone(),
            None => r
                .worst
                .iter()
                .map(|(k, v)| format!("{k} {v:.3e}"))
                .collect::<Vec<_>>()
                .join(", "),
        };
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {:.2} | {} | {} |",
            r.material,
            r.budget,
            r.grid,
            r.bytes,
            r.plan_s,
            worst,
            if r.holds { "yes" } else { "NO" }
        );
    }
    s
}

/// The median of the file sizes of the rows of one budget that were planned.
pub fn median_bytes(rows: &[ZooRow], budget: &str) -> Option<usize> {
    let mut b: Vec<usize> = rows
        .iter()
        .filter(|r| r.budget == budget && r.error.is_none())
        .map(|r| r.bytes)
        .collect();
    b.sort_unstable();
    (!b.is_empty()).then(|| b[b.len() / 2])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::Brdf;

    #[test]
    fn the_zoo_has_30_distinct_materials_that_parse_and_span_the_hard_cases() {
        let zoo = materials();
        assert!(zoo.len() >= 30, "{} materials", zoo.len());
        let mut names: Vec<&str> = zoo.iter().map(|m| m.name.as_str()).collect();
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), zoo.len(), "names repeat");
        let mut anisotropic = 0;
        for m in &zoo {
            let model =
                crate::model::Model::parse(&m.spec).unwrap_or_else(|e| panic!("{}: {e}", m.name));
            if !model.is_isotropic() {
                anisotropic += 1;
            }
        }
        assert!(anisotropic >= 2);
    }

    /// The random families: the same materials from the same seed, others from another,
    /// every family drawn in a long run, every spec a model that parses, and the parameters
    /// spanning their ranges (the narrowest peak near 5e-4 and the broadest near 0.6 among
    /// 400 draws: log-uniform, not clustered).
    #[test]
    fn random_materials_are_seeded_parse_and_span_their_families() {
        let a = random_materials(400, 7);
        let b = random_materials(400, 7);
        let c = random_materials(400, 8);
        assert_eq!(
            a.iter().map(|m| &m.spec).collect::<Vec<_>>(),
            b.iter().map(|m| &m.spec).collect::<Vec<_>>()
        );
        assert_ne!(a[0].spec, c[0].spec);
        let mut tags = std::collections::BTreeSet::new();
        let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
        for m in &a {
            crate::model::Model::parse(&m.spec).unwrap_or_else(|e| panic!("{}: {e}", m.spec));
            tags.insert(m.name.split('-').skip(2).collect::<Vec<_>>().join("-"));
            if m.name.contains("body-peak") {
                let alpha: f64 = m
                    .spec
                    .split("alpha=")
                    .nth(1)
                    .unwrap()
                    .split(',')
                    .next()
                    .unwrap()
                    .parse()
                    .unwrap();
                assert!((5e-4..=0.6).contains(&alpha), "{}", m.spec);
                lo = lo.min(alpha);
                hi = hi.max(alpha);
            }
        }
        assert_eq!(tags.len(), 8, "{tags:?}");
        assert!(lo < 1.5e-3 && hi > 0.3, "α from {lo} to {hi}");
    }
}
