//! `brdfpack check`: round-trip error of a table (or any source) against a reference.

use super::common::{LookupArg, Source};
use crate::check::{CheckOptions, check};
use clap::Args;

/// Bounds on metrics: exceeding any makes the command exit 1 (a build step can gate on it).
#[derive(Args, Debug, Clone, Default)]
pub struct Bounds {
    /// Fail (exit 1) when log_rmse on the uniform set exceeds this.
    #[arg(long, value_name = "X", help_heading = "Bounds")]
    pub max_log_rmse: Option<f64>,
    /// Fail when rmse exceeds this.
    #[arg(long, value_name = "X", help_heading = "Bounds")]
    pub max_rmse: Option<f64>,
    /// Fail when rel_rmse exceeds this.
    #[arg(long, value_name = "X", help_heading = "Bounds")]
    pub max_rel_rmse: Option<f64>,
    /// Fail when max_abs exceeds this.
    #[arg(long, value_name = "X", help_heading = "Bounds")]
    pub max_max_abs: Option<f64>,
    /// Fail when rel_rmse_core exceeds this.
    #[arg(long, value_name = "X", help_heading = "Bounds")]
    pub max_rel_rmse_core: Option<f64>,
    /// Fail when p99_rel_core exceeds this.
    #[arg(long, value_name = "X", help_heading = "Bounds")]
    pub max_p99_rel_core: Option<f64>,
    /// Fail when albedo_err (max |Δ directional albedo| over 16 θi) exceeds this.
    #[arg(long, value_name = "X", help_heading = "Bounds")]
    pub max_albedo_err: Option<f64>,
}

impl Bounds {
    pub fn list(&self) -> Vec<(&'static str, f64)> {
        [
            ("log_rmse", self.max_log_rmse),
            ("rmse", self.max_rmse),
            ("rel_rmse", self.max_rel_rmse),
            ("max_abs", self.max_max_abs),
            ("rel_rmse_core", self.max_rel_rmse_core),
            ("p99_rel_core", self.max_p99_rel_core),
            ("albedo_err", self.max_albedo_err),
        ]
        .into_iter()
        .filter_map(|(n, v)| v.map(|v| (n, v)))
        .collect()
    }

    /// Validates the bounds themselves (finite, non-negative).
    pub fn validate(&self) -> crate::Result<()> {
        for (n, v) in self.list() {
            if !(v.is_finite() && v >= 0.0) {
                return Err(crate::Error::input(format!(
                    "--max-{}: {v} is not a finite non-negative number",
                    n.replace('_', "-")
                )));
            }
        }
        Ok(())
    }
}

#[derive(Args, Debug)]
pub struct CheckArgs {
    /// The table (or model) to check.
    pub candidate: String,
    /// The reference: a model spec or a table file.
    #[arg(long)]
    pub against: String,
    /// Interpolation used for tables.
    #[arg(long, value_enum, default_value_t = LookupArg::Linear)]
    pub interp: LookupArg,
    /// Pairs in the uniform set (the other sets use a quarter as many).
    #[arg(long, default_value_t = 65_536)]
    pub samples: usize,
    /// Seed of the sample sets (printed in the report).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Only the uniform set.
    #[arg(long)]
    pub uniform_only: bool,
    /// Machine-readable report (one JSON object) instead of the table.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub bounds: Bounds,
    /// Also draw the error views of this check (sphere, lobes, slice, albedo of the candidate
    /// against the reference) into FILE (.png or .svg; docs/plots.md).
    #[arg(long, value_name = "FILE")]
    pub plot: Option<std::path::PathBuf>,
    #[command(flatten)]
    pub picture: super::plot::PictureArgs,
    #[command(flatten)]
    pub report: super::common::ReportTarget,
    /// The reference seen with the scene's channels (the domain is the candidate table's).
    #[command(flatten)]
    pub scene: super::common::SceneArgs,
}

pub fn run(a: CheckArgs) -> anyhow::Result<i32> {
    a.bounds.validate()?;
    validate_samples(a.samples)?;
    // Picture options are checked before any work.
    let picture = match &a.plot {
        Some(p) => Some((super::plot::image_format(p, None)?, a.picture.options()?)),
        None => None,
    };
    let cand = Source::open(&a.candidate)?;
    let cells = match &cand {
        Source::Table(t) => Some((t.grid().clone(), t.valid().to_vec())),
        Source::Model(_) | Source::Measured(_) => None,
    };
    let table_of = |s: &Source| match s {
        Source::Table(t) if picture.is_some() => Some(t.clone()),
        _ => None,
    };
    let cand_table = table_of(&cand);
    let cand = cand.into_brdf(a.interp.into())?;
    let reference = Source::open(&a.against)?;
    let reference_table = table_of(&reference);
    let scene = a.scene.load(&mut crate::reads::ReadSet::new())?;
    let reference = scene.restrict_source(reference.into_brdf(a.interp.into())?)?;
    let report = check(
        reference.as_ref(),
        cand.as_ref(),
        cells.as_ref().map(|(g, v)| (g, v.as_slice())),
        &CheckOptions {
            samples: a.samples,
            seed: a.seed,
            all_sets: !a.uniform_only,
        },
    )?;
    let failed = verdict(&report, &a.bounds);
    let (reference, cand) = (
        crate::plot::Subject {
            label: a.against.clone(),
            brdf: reference,
            table: reference_table,
        },
        crate::plot::Subject {
            label: a.candidate.clone(),
            brdf: cand,
            table: cand_table,
        },
    );
    if let (Some(path), Some((format, opts))) = (&a.plot, &picture) {
        super::plot::write_picture(
            crate::plot::View::Report,
            &cand,
            Some(&reference),
            opts,
            path,
            *format,
        )?;
    }
    if a.json {
        let mut v = serde_json::to_value(&report)?;
        v["bounds_exceeded"] = serde_json::json!(failed);
        outln!("{v}");
    } else {
        out!("{}", report.to_table());
        if a.bounds.list().is_empty() {
            outln!("verdict: no bounds given");
        } else if failed.is_empty() {
            outln!("verdict: pass (all bounds met)");
        } else {
            outln!("verdict: FAIL ({})", failed.join("; "));
        }
    }
    Ok(if failed.is_empty() { 0 } else { 1 })
}

/// The bounds a report exceeds, as human strings.
pub fn verdict(report: &crate::check::CheckReport, bounds: &Bounds) -> Vec<String> {
    bounds
        .list()
        .into_iter()
        .filter_map(|(name, max)| {
            let v = report.bounded_value(name)?;
            (v > max).then(|| format!("{name} = {v:.4e} > {max}"))
        })
        .collect()
}

/// `--samples` must be in [1, 10^8] and its pairs and values fit the memory budget (a
/// sample set is held in memory).
pub fn validate_samples(n: usize) -> crate::Result<()> {
    validate_pairs("--samples", n)
}

/// A count of direction pairs held in memory (`--samples`, `--pairs`): in [1, 10^8] and
/// within the memory budget.
pub fn validate_pairs(flag: &str, n: usize) -> crate::Result<()> {
    if n == 0 || n > 100_000_000 {
        return Err(crate::Error::input(format!(
            "{flag} {n} is out of range [1, 100000000]"
        )));
    }
    crate::memory::require(&format!("{flag} {n}"), crate::memory::pair_bytes(n))
}
