//! Reference values of spec/models.md: the shared fixtures (`../shared/fixtures/models`, from
//! independent implementations) and the project's own `fixtures/models` (from
//! `fixtures/models/make.py`, a straightforward Python transcription of the spec).

mod common;

use brdfpack::brdf::Brdf;
use brdfpack::geometry::Vec3;
use brdfpack::model::Model;
use serde_json::Value;
use std::path::{Path, PathBuf};

use common::shared_dir;

fn vec3(v: &Value) -> Vec3 {
    let a = v.as_array().expect("direction array");
    Vec3::new(
        a[0].as_f64().unwrap(),
        a[1].as_f64().unwrap(),
        a[2].as_f64().unwrap(),
    )
}

/// Worst relative error of one file, and the failures (line, message).
struct FileResult {
    lines: usize,
    worst_rel: f64,
    worst_line: usize,
    failures: Vec<String>,
}

fn check_file(path: &Path) -> FileResult {
    let text = std::fs::read_to_string(path).expect("read fixture");
    let mut res = FileResult {
        lines: 0,
        worst_rel: 0.0,
        worst_line: 0,
        failures: Vec::new(),
    };
    let mut cache: Option<(Value, Model)> = None;
    for (i, line) in text.lines().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        res.lines += 1;
        let rec: Value = serde_json::from_str(line).expect("fixture line is JSON");
        let spec = &rec["model"];
        if cache.as_ref().is_none_or(|(s, _)| s != spec) {
            match Model::from_json(spec) {
                Ok(m) => cache = Some((spec.clone(), m)),
                Err(e) => {
                    res.failures
                        .push(format!("line {}: model does not build: {e}", i + 1));
                    continue;
                }
            }
        }
        let model = &cache.as_ref().unwrap().1;
        let (wi, wo) = (vec3(&rec["wi"]), vec3(&rec["wo"]));
        let want: Vec<f64> = rec["f"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect();
        let tol = rec["tol"].as_f64().unwrap();
        if model.channels().len() != want.len() {
            res.failures.push(format!(
                "line {}: model has {} channels, fixture {}",
                i + 1,
                model.channels().len(),
                want.len()
            ));
            continue;
        }
        let mut got = vec![0.0; want.len()];
        model.eval(wi, wo, &mut got);
        for (ch, (g, f)) in got.iter().zip(&want).enumerate() {
            let rel = (g - f).abs() / f.abs().max(1e-300);
            if rel > res.worst_rel || rel.is_nan() {
                res.worst_rel = if rel.is_nan() { f64::INFINITY } else { rel };
                res.worst_line = i + 1;
            }
            // NaN fails the comparison and so counts as a failure.
            let within = (g - f).abs() <= tol * f.abs().max(1e-300);
            if !within {
                res.failures.push(format!(
                    "line {} ({}), channel {ch}: got {g:e}, want {f:e} (rel {rel:.2e} > tol {tol:e})",
                    i + 1,
                    rec["case"].as_str().unwrap_or("?"),
                ));
            }
        }
    }
    res
}

fn check_dir(dir: &Path, skip: &[&str]) -> usize {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .expect("fixture dir")
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "jsonl"))
        .filter(|p| !skip.iter().any(|s| p.file_name().unwrap() == *s))
        .collect();
    files.sort();
    let mut report = Vec::new();
    let mut failed = false;
    for f in &files {
        let r = check_file(f);
        let name = f.file_name().unwrap().to_string_lossy().to_string();
        report.push(format!(
            "{name}: {} lines, worst relative error {:.3e} (line {}), {} failures",
            r.lines,
            r.worst_rel,
            r.worst_line,
            r.failures.len()
        ));
        if !r.failures.is_empty() {
            failed = true;
            report.extend(r.failures.iter().take(5).map(|s| format!("  {s}")));
        }
    }
    let summary = report.join("\n");
    println!("{summary}");
    assert!(!failed, "fixture mismatches:\n{summary}");
    files.len()
}

#[test]
fn shared_fixtures_all_pass() {
    let Some(shared) = shared_dir() else {
        println!("skipped: ../shared (or $BRDFPACK_SHARED) not found");
        return;
    };
    let dir = shared.join("fixtures/models");
    if !dir.is_dir() {
        println!("skipped: {} not found", dir.display());
        return;
    }
    // Every file, htsg.jsonl included (HTSG through `Model::from_json`; its numerics and
    // the two lines near 1e-11 are explained in docs/htsg.md).
    let n = check_dir(&dir, &[]);
    assert_eq!(n, 10, "expected the 10 fixture files in {}", dir.display());
}

#[test]
fn project_fixtures_all_pass() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/models");
    let n = check_dir(&dir, &[]);
    assert!(
        n >= 10,
        "expected the fixture files of fixtures/models/make.py, found {n}"
    );
}
