//! `brdfpack pack`: the whole job in one command — tabulate, encode, write, read back,
//! check against the source, and report sizes, times and errors.

use super::check::{Bounds, verdict};
use super::common::{Lookup, SamplingArgs, Source, stderr_is_terminal};
use crate::check::{CheckOptions, check, fmt_num};
use crate::codec::search::{Budget, MARGIN, held_out_set, search};
use crate::codec::{CodecRequest, CodecSpec};
use crate::grid::parse_grid_spec;
use crate::io::{atomic, native};
use crate::model::Model;
use crate::pack_search::{
    GridOutcome, GridTrial, always_searched, default_grid_spec, grid_ladder, search_grids,
};
use crate::table::{Interp, InterpolatedTable};
use crate::tabulate::tabulate;
use clap::Args;
use serde::Serialize;
use std::path::PathBuf;
use std::time::Instant;

#[derive(Args, Debug)]
pub struct PackArgs {
    /// Model spec or table file; default: the built-in material (GGX α = 0.2 gold).
    pub source: Option<String>,
    /// Output file (`-` for stdout; the report then goes to stderr).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Grid spec (see `tabulate --help`). Default: `merl` for isotropic reciprocal sources,
    /// `spherical3:90x90x180` for isotropic non-reciprocal ones (measured data),
    /// `halfdiff4:64` for anisotropic ones.
    #[arg(long)]
    pub grid: Option<String>,
    /// Pairs in the uniform check set.
    #[arg(long, default_value_t = 65_536)]
    pub samples: usize,
    /// Seed of the check's sample sets.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    #[command(flatten)]
    pub symmetry: SamplingArgs,
    /// Codec of the file (docs/compression.md), e.g. `lossless` (bit-exact) or
    /// `dct:step=0.05`. Default: the smallest file whose decoded table is within
    /// `log_rmse=0.002,p99_rel_core=0.05` of the tabulated one (a budget search).
    #[arg(long, conflicts_with = "max_error")]
    pub codec: Option<String>,
    /// Error budget, e.g. `log_rmse=0.01,p99_rel_core=0.2`: the smallest file meeting it on
    /// the uniform set is chosen. For a model the error is measured against the model and,
    /// without `--grid`, the grid resolution is searched too (docs/compression.md); for a
    /// table or measured file, against the tabulated table.
    #[arg(long)]
    pub max_error: Option<String>,
    /// One JSON object instead of report lines.
    #[arg(long)]
    pub json: bool,
    /// No report (errors and exceeded bounds still print).
    #[arg(short, long)]
    pub quiet: bool,
    #[command(flatten)]
    pub bounds: Bounds,
}

#[derive(Serialize)]
struct PackReport {
    source: String,
    grid: String,
    codec: CodecSpec,
    cells: usize,
    valid_cells: usize,
    channels: usize,
    bytes: usize,
    raw_f32_bytes: usize,
    compression_ratio: f64,
    bits_per_sample: f64,
    tabulate_s: f64,
    encode_s: f64,
    decode_s: f64,
    check: crate::check::CheckReport,
    bounds_exceeded: Vec<String>,
    /// `--max-error` against a model: the budget, the search's sets and every grid tried.
    #[serde(skip_serializing_if = "Option::is_none")]
    budget: Option<BudgetReport>,
    #[serde(skip_serializing_if = "Option::is_none")]
    grid_search: Option<Vec<GridTrial>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    grid_search_s: Option<f64>,
}

/// The budget `pack` searches with when neither `--codec` nor `--max-error` is given: issue
/// #5's "production" budget on the codec's own error (the decoded table against the tabulated
/// one), which the lossless fallback always meets, so a coarse grid never makes it fail.
pub const DEFAULT_MAX_ERROR: &str = "log_rmse=0.002,p99_rel_core=0.05";

#[derive(Serialize)]
struct BudgetReport {
    bounds: Vec<(String, f64)>,
    /// True when the budget is [`DEFAULT_MAX_ERROR`] (no `--codec`, no `--max-error`).
    default: bool,
    /// What the error is measured against: `model` or `table`.
    against: &'static str,
    /// Against the table: the chosen file's metrics on the search's set and on the held-out
    /// set (against a model they are in `grid_search`).
    #[serde(skip_serializing_if = "Option::is_none")]
    measured: Option<crate::check::Metrics>,
    #[serde(skip_serializing_if = "Option::is_none")]
    measured_held_out: Option<crate::check::Metrics>,
    set: String,
    samples: usize,
    seed: u64,
    #[serde(skip_serializing_if = "Option::is_none")]
    held_out_seed: Option<u64>,
    margin: f64,
}

/// The file to write and how it was made.
struct Packed {
    table: crate::table::Table,
    codec: CodecSpec,
    bytes: Vec<u8>,
    tabulate_s: f64,
    encode_s: f64,
    grid_search: Option<(Vec<GridTrial>, f64)>,
    /// A codec search against the table: the chosen file's metrics (search set, held-out).
    codec_error: Option<(crate::check::Metrics, Option<crate::check::Metrics>)>,
}

pub fn run(a: PackArgs) -> anyhow::Result<i32> {
    a.bounds.validate()?;
    super::check::validate_samples(a.samples)?;
    let source = match &a.source {
        Some(s) => a.symmetry.apply(Source::open(s)?),
        None => Source::Model(Model::default_material()),
    };
    let is_model = matches!(source, Source::Model(_));
    let src = source.into_brdf(Lookup::Linear)?;
    let explicit = a.max_error.as_deref().map(Budget::parse).transpose()?;
    // A model is the truth the file stands for: a budget the user gives bounds the error
    // against it. The default budget bounds the codec's error alone.
    let against_model = explicit.is_some() && is_model;
    let default_budget = explicit.is_none() && a.codec.is_none();
    let budget = match explicit {
        Some(b) => Some(b),
        None if default_budget => Some(Budget::parse(DEFAULT_MAX_ERROR)?),
        None => None,
    };
    let show_progress = stderr_is_terminal() && !a.quiet;
    let tab_opts = a.symmetry.options(show_progress);
    let spinner = |what: String| {
        show_progress.then(|| {
            let b = indicatif::ProgressBar::new_spinner();
            b.set_message(what);
            b.enable_steady_tick(std::time::Duration::from_millis(120));
            b
        })
    };
    let packed = match &budget {
        Some(budget) if against_model => {
            let (ladder, always) = match &a.grid {
                Some(g) => (vec![g.as_str()], 1),
                None => (grid_ladder(src.as_ref()), always_searched(src.as_ref())),
            };
            let set = crate::check::SampleSet::uniform(a.samples, a.seed);
            let t0 = Instant::now();
            let progress = spinner(format!(
                "searching grids and codecs for {} against the model",
                budget.describe()
            ));
            let found = search_grids(src.as_ref(), &ladder, always, budget, &set, 19, &tab_opts);
            if let Some(p) = progress {
                p.finish_and_clear();
            }
            let found = found?;
            let total_s = t0.elapsed().as_secs_f64();
            Packed {
                table: found.choice.table,
                codec: found.choice.codec,
                bytes: found.choice.file,
                tabulate_s: found.choice.tabulate_s,
                encode_s: found.choice.search_s,
                grid_search: Some((found.trials, total_s)),
                codec_error: None,
            }
        }
        _ => {
            let grid = match &a.grid {
                Some(g) => parse_grid_spec(g)?,
                None => default_grid(src.as_ref()),
            };
            let t0 = Instant::now();
            let table = tabulate(src.as_ref(), &grid, &tab_opts)?;
            let tabulate_s = t0.elapsed().as_secs_f64();
            let t1 = Instant::now();
            let (codec, codec_error) = match (&a.codec, &budget) {
                (_, Some(budget)) => {
                    let set = crate::check::SampleSet::uniform(a.samples, a.seed);
                    let progress = spinner(format!(
                        "searching codecs for {} against the table",
                        budget.describe()
                    ));
                    let found = search(&table, budget, &set, 19);
                    if let Some(p) = progress {
                        p.finish_and_clear();
                    }
                    let best = found?.best;
                    (best.spec, Some((best.metrics, best.held_out)))
                }
                // Without --codec the default budget is set, so this is `--codec`'s.
                (c, None) => (
                    CodecRequest::parse(c.as_deref().unwrap_or("lossless"))?.resolve(&table)?,
                    None,
                ),
            };
            let bytes = native::to_bytes(&table, &codec)?;
            Packed {
                table,
                codec,
                bytes,
                tabulate_s,
                encode_s: t1.elapsed().as_secs_f64(),
                grid_search: None,
                codec_error,
            }
        }
    };
    let Packed {
        table,
        codec,
        bytes,
        tabulate_s,
        encode_s,
        grid_search,
        codec_error,
    } = packed;
    let grid = table.grid().clone();
    // Check what a reader will get: decode the bytes we are about to write.
    let t2 = Instant::now();
    let back = native::from_bytes(&bytes, &a.output)?;
    let decode_s = t2.elapsed().as_secs_f64();
    let cells = (back.grid().clone(), back.valid().to_vec());
    let cand = InterpolatedTable {
        table: back,
        interp: Interp::Linear,
    };
    let report = check(
        src.as_ref(),
        &cand,
        Some((&cells.0, &cells.1)),
        &CheckOptions {
            samples: a.samples,
            seed: a.seed,
            all_sets: true,
        },
    )?;
    // The search measured these very bytes on this very set; a mismatch would be a bug, and
    // a file that misses its budget must never be written.
    if let (Some(b), true) = (&budget, against_model)
        && !b.met_by(&report.uniform.combined)
    {
        return Err(crate::Error::Failure(format!(
            "--max-error: the packed file misses the budget against the model on the check \
             ({}); no file written",
            b.exceeded(&report.uniform.combined).join(", ")
        ))
        .into());
    }
    atomic::write_output(&a.output, &bytes)?;
    let failed = verdict(&report, &a.bounds);
    let raw = table.data().len() * 4;
    let r = PackReport {
        source: src.describe(),
        grid: grid.describe(),
        codec,
        cells: grid.cells(),
        valid_cells: table.valid_count(),
        channels: table.channels().len(),
        bytes: bytes.len(),
        raw_f32_bytes: raw,
        compression_ratio: raw as f64 / bytes.len() as f64,
        bits_per_sample: bytes.len() as f64 * 8.0 / table.data().len() as f64,
        tabulate_s,
        encode_s,
        decode_s,
        check: report,
        bounds_exceeded: failed.clone(),
        budget: budget.map(|b| {
            let set = crate::check::SampleSet::uniform(0, a.seed);
            let (measured, measured_held_out) =
                codec_error.map_or((None, None), |(m, h)| (Some(m), h));
            BudgetReport {
                bounds: b.bounds,
                default: default_budget,
                against: if against_model { "model" } else { "table" },
                measured,
                measured_held_out,
                set: set.name.clone(),
                samples: a.samples,
                seed: a.seed,
                held_out_seed: held_out_set(&set).and_then(|h| h.seed),
                margin: MARGIN,
            }
        }),
        grid_search_s: grid_search.as_ref().map(|g| g.1),
        grid_search: grid_search.map(|g| g.0),
    };
    let to_stderr = a.output.as_os_str() == "-";
    let out = if a.json {
        format!("{}\n", serde_json::to_string(&r)?)
    } else {
        human(&r)
    };
    if !a.quiet {
        if to_stderr {
            eprint!("{out}");
        } else {
            out!("{out}");
        }
    } else if !failed.is_empty() {
        eprintln!("brdfpack: bounds exceeded: {}", failed.join("; "));
    }
    Ok(if failed.is_empty() { 0 } else { 1 })
}

/// A grid that respects the source's symmetries at about MERL's resolution.
fn default_grid(src: &dyn crate::brdf::Brdf) -> crate::grid::Grid {
    parse_grid_spec(default_grid_spec(src)).expect("built-in grid specs parse")
}

fn human(r: &PackReport) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let u = &r.check.uniform;
    let _ = writeln!(s, "source        {}", r.source);
    let _ = writeln!(
        s,
        "grid          {} ({} cells, {} valid)",
        r.grid, r.cells, r.valid_cells
    );
    let _ = writeln!(
        s,
        "size          {} bytes ({:.2}x smaller than {} bytes of raw f32, {:.2} bits/sample)",
        r.bytes, r.compression_ratio, r.raw_f32_bytes, r.bits_per_sample
    );
    let _ = writeln!(
        s,
        "time          tabulate {:.3} s, encode {:.3} s, decode {:.3} s",
        r.tabulate_s, r.encode_s, r.decode_s
    );
    if let Some(b) = &r.budget {
        let bounds: Vec<String> = b.bounds.iter().map(|(k, v)| format!("{k} ≤ {v}")).collect();
        let _ = writeln!(
            s,
            "budget        {}{} against the {} ({} set, {} pairs, seed {}: bounds × {}{})",
            bounds.join(", "),
            if b.default {
                " (default; --max-error or --codec to change)"
            } else {
                ""
            },
            b.against,
            b.set,
            b.samples,
            b.seed,
            b.margin,
            b.held_out_seed
                .map_or(String::new(), |h| format!("; held-out seed {h}: bounds"))
        );
        if let Some(m) = &b.measured {
            let values = |m: &crate::check::Metrics| {
                b.bounds
                    .iter()
                    .map(|(k, _)| format!("{k} {}", fmt_num(m.get(k))))
                    .collect::<Vec<_>>()
                    .join(", ")
            };
            let _ = writeln!(
                s,
                "codec error   {} against the table{}",
                values(m),
                b.measured_held_out
                    .as_ref()
                    .map_or(String::new(), |h| format!(" (held-out: {})", values(h)))
            );
        }
    }
    if let (Some(trials), Some(t)) = (&r.grid_search, r.grid_search_s) {
        let _ = writeln!(
            s,
            "grid search   {} grid(s) in {t:.1} s; error of the uncompressed table, then of the file, against the model:",
            trials.len()
        );
        let names: Vec<&str> = r
            .budget
            .as_ref()
            .map(|b| b.bounds.iter().map(|(k, _)| k.as_str()).collect())
            .unwrap_or_default();
        let values = |m: &crate::check::Metrics| {
            names
                .iter()
                .map(|k| format!("{k} {}", fmt_num(m.get(k))))
                .collect::<Vec<_>>()
                .join(", ")
        };
        for tr in trials {
            let mark = if tr.chosen { "*" } else { " " };
            let _ = writeln!(
                s,
                "  {mark} {} ({} cells, tabulated in {:.1} s): table {}",
                tr.grid,
                tr.cells,
                tr.tabulate_s,
                values(&tr.tabulation)
            );
            let _ = match &tr.outcome {
                GridOutcome::Packed {
                    bytes,
                    metrics,
                    search_s,
                    ..
                } => writeln!(
                    s,
                    "      {bytes} bytes, {} (codec search {search_s:.1} s){}",
                    values(metrics),
                    if tr.chosen { "  <- chosen" } else { "" }
                ),
                GridOutcome::Skipped { reason } => writeln!(s, "      skipped: {reason}"),
            };
        }
    }
    let _ = writeln!(
        s,
        "check         uniform set, {} pairs, seed {}, linear interpolation; ε = {:.3e}",
        u.samples,
        u.seed.unwrap_or(0),
        u.combined.epsilon
    );
    let worst = r.check.worst_other.as_ref();
    for name in [
        "log_rmse",
        "rmse",
        "rel_rmse",
        "max_abs",
        "max_rel",
        "rel_rmse_core",
        "p99_rel_core",
        "nonfinite",
        "negative",
    ] {
        let v = fmt_num(u.combined.get(name));
        let _ = match worst.and_then(|w| w.get(name)) {
            Some(w) => writeln!(
                s,
                "{name:<13} {v:<11}  (worst of grazing/specular/cells: {})",
                fmt_num(Some(w))
            ),
            None => writeln!(s, "{name:<13} {v}"),
        };
    }
    if let Some(a) = r.check.albedo_err {
        let _ = writeln!(
            s,
            "albedo_err    {}  (max |Δ directional albedo| over 16 θi)",
            fmt_num(Some(a))
        );
    }
    if !r.bounds_exceeded.is_empty() {
        let _ = writeln!(s, "verdict       FAIL ({})", r.bounds_exceeded.join("; "));
    }
    s
}
