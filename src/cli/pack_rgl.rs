//! `brdfpack pack FILE.bsdf` without `--grid`: the RGL file packed in its own
//! parameterization (`plan::rgl`, issue #19), written, read back and checked against the
//! source as `pack` does for tables.

use super::pack::PackArgs;
use crate::brdf::Brdf;
use crate::check::{CheckOptions, check};
use crate::codec::tensor::TensorCoding;
use crate::io::atomic;
use crate::io::rgl::RglBsdf;
use crate::plan::budget::Budget;
use crate::plan::estimate::{CONFIDENCE_Z, Estimate};
use crate::plan::pack::PackSettings;
use crate::plan::rate::Effort;
use crate::plan::rgl::{RglAttempt, plan_rgl};
use crate::table::Provenance;
use serde::Serialize;
use std::time::Instant;

#[derive(Serialize)]
struct RglPackReport {
    output: String,
    source: String,
    /// Always `brdfpack-rgl`: the RGL file in its own parameterization.
    form: &'static str,
    coding: TensorCoding,
    vndf: &'static str,
    /// `stored`, or `derived` from the NDF (times the file's constant).
    sigma: &'static str,
    bytes: usize,
    /// The colour tensor's values as f32.
    raw_f32_bytes: usize,
    compression_ratio: f64,
    encode_s: f64,
    decode_s: f64,
    check: crate::check::CheckReport,
    bounds_exceeded: Vec<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    budget: Option<RglBudgetReport>,
    timings: Vec<(String, f64)>,
}

#[derive(Serialize)]
struct RglBudgetReport {
    bounds: Vec<(String, f64)>,
    default: bool,
    effort: Effort,
    against: &'static str,
    /// The file against the source (estimation set, upper values, check set).
    file: Estimate,
    /// The form alone: exact colour values, VNDF as stored or derived.
    form_alone: Estimate,
    estimate_samples: usize,
    confidence_z: f64,
    samples: usize,
    seed: u64,
    codings: Vec<RglAttempt>,
}

/// Packs `source` (an RGL file or a packed one) with `budget`, or losslessly without one.
pub fn run(
    a: &PackArgs,
    source: RglBsdf,
    budget: Option<Budget>,
    default_budget: bool,
    effort: Effort,
    reads: &crate::reads::ReadSet,
) -> anyhow::Result<i32> {
    if a.full_check && !a.quiet {
        eprintln!(
            "brdfpack: note: --full-check: an RGL file in its own parameterization has no grid \
             cells; the uniform, grazing and specular sets are checked"
        );
    }
    let bar = super::common::Bar::new(a.quiet);
    let progress = |stage: &str| bar.stage(stage);
    let settings = PackSettings {
        // Lossless (no budget): the budget only names what is reported.
        budget: budget
            .clone()
            .unwrap_or_else(|| Budget::parse(crate::plan::budget::PRODUCTION).expect("valid")),
        effort,
        check_samples: a.samples,
        check_seed: a.seed,
    };
    // The format says the file is packed in its own parameterization; the description is
    // the source's (a preview file is 4 KB: no path, which says nothing of the material).
    let provenance = Provenance {
        source: source.describe(),
        tool: crate::TOOL_VERSION.to_string(),
        notes: Vec::new(),
    };
    let t0 = Instant::now();
    let planned = plan_rgl(&source, &settings, budget.is_none(), &provenance, &progress);
    bar.finish();
    let planned = planned?;
    let encode_s = t0.elapsed().as_secs_f64();
    let mut timings = planned.timings;
    let t = Instant::now();
    let back = RglBsdf::from_bytes(&planned.bytes, &a.output.display().to_string())?;
    let decode_s = t.elapsed().as_secs_f64();
    timings.push(("read back".to_string(), decode_s));
    let t = Instant::now();
    let report = check(
        &source,
        &back,
        None,
        &CheckOptions {
            samples: a.samples,
            seed: a.seed,
            all_sets: true,
        },
    )?;
    timings.push(("check".to_string(), t.elapsed().as_secs_f64()));
    if let Some(code) = super::pack::refused(&report, budget.as_ref(), a)? {
        return Ok(code);
    }
    atomic::write_output(&a.output, &planned.bytes)?;
    a.depfile.write(&[a.output.as_path()], reads)?;
    let info = source.info();
    let raw = info.entries_per_channel * source.channels().len() * 4;
    let r = RglPackReport {
        output: a.output.display().to_string(),
        source: source.describe(),
        form: crate::io::rgl::packed::FORMAT,
        coding: planned.options.coding.clone(),
        vndf: planned.options.vndf.name(),
        sigma: if planned.options.derive_sigma.is_some() {
            "derived"
        } else {
            "stored"
        },
        bytes: planned.bytes.len(),
        raw_f32_bytes: raw,
        compression_ratio: raw as f64 / planned.bytes.len() as f64,
        encode_s,
        decode_s,
        check: report,
        // A file is written only within every bound (`refused`).
        bounds_exceeded: Vec::new(),
        budget: budget.as_ref().map(|b| RglBudgetReport {
            bounds: b.bounds.clone(),
            default: default_budget,
            effort,
            against: "source",
            file: planned.estimate.clone(),
            form_alone: planned.floor.clone(),
            estimate_samples: planned.estimate_samples,
            confidence_z: CONFIDENCE_Z,
            samples: a.samples,
            seed: a.seed,
            codings: planned.attempts.clone(),
        }),
        timings,
    };
    if a.verbose {
        for (stage, secs) in &r.timings {
            eprintln!("brdfpack: {secs:>8.3} s  {stage}");
        }
        eprint!("{}", human(&r));
    }
    if a.json {
        super::pack::print_json(&r, a)?;
    }
    Ok(0)
}

fn human(r: &RglPackReport) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let u = &r.check.uniform;
    let _ = writeln!(s, "output        {}", r.output);
    let _ = writeln!(s, "source        {}", r.source);
    let coding = match &r.coding {
        TensorCoding::Lossless => "lossless (f32 + zstd)".to_string(),
        TensorCoding::Dct { step, deadzone, .. } => format!(
            "signed log, colour KLT, DCT, context-coded (step {step:.4e}, dead zone {deadzone})"
        ),
    };
    let _ = writeln!(
        s,
        "form          RGL tensor in its own parameterization ({}): colour {coding}; VNDF {}; sigma {}",
        r.form, r.vndf, r.sigma
    );
    let _ = writeln!(
        s,
        "size          {} bytes ({:.1}% of the {} bytes of the colour tensor's f32{})",
        r.bytes,
        100.0 / r.compression_ratio,
        r.raw_f32_bytes,
        if r.vndf == "stored" {
            ", with every other field, the VNDF included"
        } else {
            ""
        }
    );
    let _ = writeln!(
        s,
        "time          plan and encode {:.3} s, decode {:.3} s",
        r.encode_s, r.decode_s
    );
    if let Some(b) = &r.budget {
        let what = format!(
            "exact colour values, VNDF {}: what the parameterization costs before coding",
            r.vndf
        );
        super::pack::write_budget(
            &mut s,
            &super::pack::BudgetLines {
                bounds: &b.bounds,
                default: b.default,
                file: &b.file,
                samples: b.samples,
                confidence_z: b.confidence_z,
                estimate_samples: b.estimate_samples,
                file_is: "the parameterization + compression",
                alone: (
                    "form alone",
                    b.form_alone.check.as_ref().unwrap_or(&b.form_alone.metrics),
                    &what,
                ),
            },
        );
    }
    let _ = writeln!(
        s,
        "check         uniform set, {} pairs, seed {}; ε = {:.3e}",
        u.samples,
        u.seed.unwrap_or(0),
        u.combined.epsilon
    );
    super::pack::write_check_metrics(&mut s, &u.combined, None);
    if !r.bounds_exceeded.is_empty() {
        let _ = writeln!(s, "verdict       FAIL ({})", r.bounds_exceeded.join("; "));
    }
    s
}
