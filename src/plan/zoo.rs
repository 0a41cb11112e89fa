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

/// Packs `spec` (a model spec or a file) within `budget` at `effort` on its default grid, and
/// measures the written file against the source on `seeds` independent uniform sets of
/// `pairs` pairs (seeds 1000 + k, none of them the planner's).
pub fn run_one(
    name: &str,
    spec: &str,
    budget_name: &str,
    budget: &Budget,
    effort: Effort,
    seeds: usize,
    pairs: usize,
) -> Result<ZooRow> {
    let src = crate::source::open_brdf(spec)?;
    let t = Instant::now();
    let planned = plan(
        PackInput::Source {
            source: src.as_ref(),
            grid: None,
            options: Default::default(),
        },
        &PackSettings {
            budget: budget.clone(),
            effort,
            check_samples: 65_536,
            check_seed: 1,
        },
        &|_| {},
    );
    let plan_s = t.elapsed().as_secs_f64();
    let row = |grid: String, bytes, worst, holds, error| ZooRow {
        material: name.to_string(),
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
    let planned = match planned {
        Ok(p) => p,
        Err(crate::Error::Failure(msg)) => {
            return Ok(row(String::new(), 0, Vec::new(), false, Some(msg)));
        }
        Err(e) => return Err(e),
    };
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
    let mut worst: Vec<(String, f64)> = budget
        .bounds
        .iter()
        .map(|(k, _)| (k.clone(), 0.0))
        .collect();
    let mut holds = true;
    for k in 0..seeds {
        let r = check_set(
            src.as_ref(),
            &cand,
            &SampleSet::uniform(pairs, 1000 + k as u64),
        )?;
        holds &= budget.met_by(&r.combined);
        for (name, w) in worst.iter_mut() {
            *w = w.max(r.combined.get(name).unwrap_or(f64::INFINITY));
        }
    }
    Ok(row(planned.grid, bytes.len(), worst, holds, None))
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
}
