//! The core pipeline on every analytic model: tables reproduce the model at their own samples,
//! and interpolation error falls as resolution rises.

mod common;

use brdfpack::brdf::Brdf;
use brdfpack::check::{SampleSet, check_set};
use brdfpack::grid::{Grid, parse_grid_spec};
use brdfpack::model::Model;
use brdfpack::table::{Interp, InterpolatedTable, Table};
use brdfpack::tabulate::{TabulateOptions, tabulate};

/// One model per fixture family (the fixture's own parameters when ../shared is present),
/// plus extra forms; the compact specs stand in when ../shared is absent.
fn models() -> Vec<(String, Model)> {
    let mut out: Vec<(String, Model)> = Vec::new();
    if let Some(dir) = common::shared_dir().map(|d| d.join("fixtures/models")) {
        let mut files: Vec<_> = std::fs::read_dir(&dir)
            .map(|r| r.filter_map(|e| e.ok()).map(|e| e.path()).collect())
            .unwrap_or_default();
        files.sort();
        for f in files {
            let name = f.file_name().unwrap().to_string_lossy().to_string();
            if !name.ends_with(".jsonl") || name.starts_with("htsg") {
                continue;
            }
            let text = std::fs::read_to_string(&f).unwrap();
            let line: serde_json::Value =
                serde_json::from_str(text.lines().next().unwrap()).unwrap();
            out.push((name, Model::from_json(&line["model"]).unwrap()));
        }
    } else {
        println!("note: ../shared absent; using built-in model specs only");
    }
    for spec in [
        "lambert:albedo=0.8/0.5/0.2",
        "phong:albedo=0.9/0.6/0.3,exponent=10",
        "blinn-phong:albedo=0.5,exponent=50",
        "ggx:alpha=0.2,fresnel=au",
        "beckmann:alpha=0.3,fresnel=dielectric,ior=1.5",
        "oren-nayar:albedo=0.7,sigma=0.3",
        "lambert:albedo=0.1 + ggx:alpha=0.3,fresnel=schlick,f0=0.04",
    ] {
        out.push((spec.to_string(), Model::parse(spec).unwrap()));
    }
    out
}

/// Max relative difference between table and model over every `step`-th valid cell, at the
/// cell's own sample position.
fn worst_at_samples(model: &Model, table: &Table, step: usize) -> f64 {
    let g = table.grid();
    let d = g.axes().len();
    let c = model.channels().len();
    let mut idx = [0usize; 4];
    let (mut a, mut b) = (vec![0.0; c], vec![0.0; c]);
    let mut worst: f64 = 0.0;
    for f in (0..g.cells()).step_by(step) {
        if !table.valid()[f] {
            continue;
        }
        g.unflatten(f, &mut idx[..d]);
        let (wi, wo) = g.cell_dirs(&idx[..d]);
        model.eval(wi, wo, &mut a);
        table.eval_into(wi, wo, Interp::Linear, &mut b);
        for k in 0..c {
            // f32 storage: 2^-24 ≈ 6e-8 relative; the bound leaves room for the interpolation
            // weight of a neighbour at ~1e-13 (the query recomputed from the sample position).
            let rel = (a[k] - b[k]).abs() / a[k].abs().max(1e-30);
            if a[k] != 0.0 || b[k] != 0.0 {
                worst = worst.max(rel);
            }
        }
    }
    worst
}

#[test]
fn merl_grid_tables_return_the_model_at_their_samples() {
    let g = Grid::merl();
    let centre = parse_grid_spec("halfdiff3:90x90x180").unwrap();
    for (name, m) in models() {
        for grid in [&g, &centre] {
            let t = tabulate(&m, grid, &TabulateOptions::default()).unwrap();
            let w = worst_at_samples(&m, &t, 7);
            assert!(
                w <= 1e-6,
                "{name} on {}: worst relative error {w:e}",
                grid.describe()
            );
        }
    }
}

#[test]
fn error_falls_as_resolution_rises() {
    let set = SampleSet::uniform(20_000, 7);
    let mut lines = Vec::new();
    for (name, m) in models() {
        let mut errs = Vec::new();
        for n in [23usize, 45, 90] {
            let g = parse_grid_spec(&format!(
                "halfdiff3:{n}x{n}x{},warp=sqrt/linear/linear",
                2 * n
            ))
            .unwrap();
            let table = tabulate(&m, &g, &TabulateOptions::default()).unwrap();
            let t = InterpolatedTable {
                table,
                interp: Interp::Linear,
            };
            let r = check_set(&m, &t, &set).unwrap();
            errs.push(r.combined.log_rmse);
        }
        let order: Vec<f64> = errs.windows(2).map(|w| (w[0] / w[1]).log2()).collect();
        lines.push(format!(
            "{name}: log_rmse {}, observed order {order:.2?}",
            fmt(&errs)
        ));
        if errs[0] < 1e-7 {
            // A constant (Lambert) is exact at every resolution: nothing to converge.
            continue;
        }
        assert!(errs[1] < errs[0] && errs[2] < errs[1], "{name}: {errs:?}");
    }
    println!("{}", lines.join("\n"));
}

#[test]
fn anisotropic_models_on_4d_grids() {
    let models = [
        "ggx:alpha_x=0.1,alpha_y=0.4,fresnel=au",
        "ward:alpha_x=0.1,alpha_y=0.3,rho_s=0.3,rho_d=0.1",
    ];
    let set = SampleSet::uniform(20_000, 11);
    for spec in models {
        let m = Model::parse(spec).unwrap();
        assert!(!m.is_isotropic(), "{spec}");
        for kind in ["spherical4", "halfdiff4"] {
            let mut errs = Vec::new();
            for n in [32usize, 64] {
                let g = parse_grid_spec(&format!("{kind}:{n}")).unwrap();
                let table = tabulate(&m, &g, &TabulateOptions::default()).unwrap();
                let w = worst_at_samples(&m, &table, 101);
                assert!(w <= 1e-6, "{spec} on {kind}:{n}: {w:e}");
                let t = InterpolatedTable {
                    table,
                    interp: Interp::Linear,
                };
                errs.push(check_set(&m, &t, &set).unwrap().combined.log_rmse);
            }
            println!("{spec} {kind}: log_rmse at 32⁴, 64⁴ = {}", fmt(&errs));
            assert!(errs[1] < errs[0], "{spec} {kind}: {errs:?}");
        }
    }
}

fn fmt(v: &[f64]) -> String {
    v.iter()
        .map(|x| format!("{x:.3e}"))
        .collect::<Vec<_>>()
        .join(", ")
}
