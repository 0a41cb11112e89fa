//! `brdfpack pack`: the whole job in one command — tabulate, encode, write, read back,
//! check against the source, and report sizes, times and errors.

use super::check::{Bounds, verdict};
use super::common::{Bar, DepfileArgs, Lookup, SamplingArgs, SceneArgs, Source};
use crate::check::{CheckOptions, check, fmt_num};
use crate::codec::{CodecRequest, CodecSpec};
use crate::grid::parse_grid_spec;
use crate::io::{atomic, native};
use crate::model::Model;
use crate::plan::budget::Budget;
use crate::plan::estimate::{CONFIDENCE_Z, Estimate};
use crate::plan::grids::default_grid;
use crate::plan::pack::{GridAttempt, PackInput, PackSettings, plan};
use crate::plan::rate::Effort;
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
    /// Grid spec (see `tabulate --help`). Default for isotropic reciprocal sources:
    /// `halfdiff3:90x90x180,warp=sqrt/grazing/linear,at=edge,horizon=extend` (MERL's grid,
    /// θd dense toward the horizon, extended below it); `spherical3:90x90x180` for isotropic
    /// non-reciprocal ones (measured data), `halfdiff4:64,warp=linear/linear/grazing/linear`
    /// for anisotropic ones; a finer grid of the same layout when the default grid alone
    /// cannot meet the budget. An RGL .bsdf without --grid is not tabulated: it is packed in
    /// its own parameterization (a .bpk of kind brdfpack-rgl; docs/rgl.md).
    #[arg(long)]
    pub grid: Option<String>,
    /// Pairs in the uniform check set; the budget is also guaranteed (at 3σ) for
    /// independent sets of this size.
    #[arg(long, default_value_t = 65_536)]
    pub samples: usize,
    /// Seed of the check's sample sets.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    #[command(flatten)]
    pub symmetry: SamplingArgs,
    /// Codec of the file (docs/compression.md), e.g. `lossless` (bit-exact) or
    /// `dct:step=0.05`. Default: the smallest file within the budget (`--max-error`).
    #[arg(long, conflicts_with = "max_error")]
    pub codec: Option<String>,
    /// Error budget of the written file against the source, e.g.
    /// `log_rmse=0.01,p99_rel_core=0.2`, or `preview` (that one) or `production`. Default `log_rmse=0.002,p99_rel_core=0.05`.
    #[arg(long)]
    pub max_error: Option<String>,
    /// Time spent for a smaller file: `fast`, `default` or `max` (several codec variants and
    /// grids; tens of seconds).
    #[arg(long, default_value = "default")]
    pub effort: String,
    /// The report as one JSON object on stdout (on stderr with `-o -`).
    #[arg(long)]
    pub json: bool,
    /// Nothing but errors (no progress bar, no notes).
    #[arg(short, long, conflicts_with = "verbose")]
    pub quiet: bool,
    /// The report (sizes, times, errors) and stage timings on stderr.
    #[arg(short, long)]
    pub verbose: bool,
    #[command(flatten)]
    pub depfile: DepfileArgs,
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Also check every grid cell (the `cells` set: the source evaluated at each valid cell;
    /// about a second on a MERL-sized grid).
    #[arg(long)]
    pub full_check: bool,
    #[command(flatten)]
    pub bounds: Bounds,
}

#[derive(Serialize)]
struct PackReport {
    output: String,
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
    /// The budget and the file's error against the source (absent with `--codec`).
    #[serde(skip_serializing_if = "Option::is_none")]
    budget: Option<BudgetReport>,
    /// What the scene left out (absent without a scene).
    #[serde(skip_serializing_if = "Option::is_none")]
    scene: Option<crate::plan::scene::SceneReport>,
    timings: Vec<(String, f64)>,
}

/// The budget `pack` plans with when neither `--codec` nor `--max-error` is given: issue
/// #5's "production" budget, against the source.
pub const DEFAULT_MAX_ERROR: &str = crate::plan::budget::PRODUCTION;

#[derive(Serialize)]
struct BudgetReport {
    bounds: Vec<(String, f64)>,
    /// True when the budget is [`DEFAULT_MAX_ERROR`] (no `--codec`, no `--max-error`).
    default: bool,
    effort: Effort,
    /// Always `source`: the written file against the source the user named.
    against: &'static str,
    /// The file against the source: metrics on the estimation set and their upper values
    /// for an independent uniform set of `samples` pairs, and the check set's metrics.
    file: Estimate,
    /// The uncompressed table against the source (tabulation and interpolation).
    grid_alone: Estimate,
    estimate_samples: usize,
    confidence_z: f64,
    samples: usize,
    seed: u64,
    grids: Vec<GridAttempt>,
}

/// The file to write and how it was made.
struct Packed {
    /// What the report says of the table (the table itself is freed once encoded).
    table: TableFacts,
    codec: CodecSpec,
    bytes: Vec<u8>,
    tabulate_s: f64,
    encode_s: f64,
    budget: Option<BudgetReport>,
    timings: Vec<(String, f64)>,
}

/// The encoded table's facts for the report.
struct TableFacts {
    grid: crate::grid::Grid,
    channels: crate::brdf::Channels,
    samples: usize,
    valid_cells: usize,
}

impl TableFacts {
    fn of(t: &crate::table::Table) -> TableFacts {
        TableFacts {
            grid: t.grid().clone(),
            channels: t.channels().clone(),
            samples: t.data().len(),
            valid_cells: t.valid_count(),
        }
    }
}

pub fn run(a: PackArgs) -> anyhow::Result<i32> {
    a.bounds.validate()?;
    super::check::validate_samples(a.samples)?;
    let effort = Effort::parse(&a.effort)?;
    let mut reads = crate::reads::ReadSet::new();
    let scene = a.scene.load(&mut reads)?;
    let source = match &a.source {
        Some(s) => a.symmetry.apply(Source::open_recording(s, &mut reads)?),
        None => Source::Model(Model::default_material()),
    };
    source.require_valid_cells()?;
    // An RGL file without --grid: packed in its own parameterization (issue #19), unless a
    // codec for tables is asked for or something the form cannot keep.
    if let Source::Measured(_) = &source
        && a.grid.is_none()
        && !scene.is_empty()
        && !a.quiet
    {
        eprintln!(
            "brdfpack: note: the RGL file is tabulated on a grid, not packed in its own \
             parameterization: a scene restricts a grid's domain and channels"
        );
    }
    if let Source::Measured(m) = &source
        && a.grid.is_none()
        && scene.is_empty()
    {
        let why = match crate::plan::rgl::unsupported(m) {
            Some(why) => Some(why),
            None if a.codec.as_deref().is_some_and(|c| c.trim() != "lossless") => Some(format!(
                "--codec {} is a codec of grid tables (only `lossless` applies to the packed form)",
                a.codec.as_deref().unwrap_or_default()
            )),
            None => None,
        };
        match why {
            None => {
                let Source::Measured(m) = source else {
                    unreachable!("matched above")
                };
                let budget = match a.max_error.as_deref().or(scene.max_error.as_deref()) {
                    Some(b) => Some(Budget::parse(b)?),
                    None if a.codec.is_none() => Some(Budget::parse(DEFAULT_MAX_ERROR)?),
                    None => None,
                };
                let default_budget = a.max_error.is_none() && a.codec.is_none();
                return super::pack_rgl::run(&a, m, budget, default_budget, effort, &reads);
            }
            Some(why) if !a.quiet => eprintln!(
                "brdfpack: note: the RGL file is tabulated on a grid, not packed in its own \
                 parameterization: {why}"
            ),
            Some(_) => {}
        }
    }
    // A table read from a regular file can be read again: on a fixed grid the planner does
    // not hold it beside the coefficients, and the check reads it again (it is as large as
    // the table planned).
    let reopenable = matches!(source, Source::Table(_))
        && a.source
            .as_deref()
            .is_some_and(|s| s != "-" && std::fs::metadata(s).is_ok_and(|m| m.is_file()));
    let src = source.into_brdf(Lookup::Linear)?;
    let full_channels = src.channels().clone();
    let src = scene.restrict_source(src)?;
    let source_name = src.describe();
    // The source read above, handed to the planner's first open instead of read again (a MERL
    // file's read is ~80 ms).
    let opened: std::sync::Mutex<Option<Box<dyn crate::brdf::Brdf>>> = Default::default();
    let open = || -> crate::Result<Box<dyn crate::brdf::Brdf>> {
        if let Some(src) = opened.lock().ok().and_then(|mut o| o.take()) {
            return Ok(src);
        }
        let spec = a.source.as_deref().unwrap_or_default();
        scene.restrict_source(
            a.symmetry
                .apply(Source::open(spec)?)
                .into_brdf(Lookup::Linear)?,
        )
    };
    let mut symmetry = a.symmetry.clone();
    if scene.isotropic == Some(true) {
        symmetry.allow_anisotropic = true;
    }
    let explicit = a
        .max_error
        .as_deref()
        .or(scene.max_error.as_deref())
        .map(Budget::parse)
        .transpose()?;
    let default_budget = explicit.is_none() && a.codec.is_none();
    let budget = match explicit {
        Some(b) => Some(b),
        None if default_budget => Some(Budget::parse(DEFAULT_MAX_ERROR)?),
        None => None,
    };
    let bar = Bar::new(a.quiet);
    let tab_opts = symmetry.options(bar.cells());
    let grid = a.grid.as_deref().map(parse_grid_spec).transpose()?;
    // A scene's θ range fixes the grid's stored domain (on the default grid when none given).
    let grid = match (grid, scene.theta_max_deg()) {
        (Some(g), _) => Some(scene.restrict_grid(&g)?),
        (None, Some(_)) => Some(scene.restrict_grid(&default_grid(src.as_ref())?)?),
        (None, None) => None,
    };
    let (packed, held) = match &budget {
        Some(budget) => {
            let progress = |stage: &str| bar.stage(stage);
            let settings = PackSettings {
                budget: budget.clone(),
                effort,
                check_samples: a.samples,
                check_seed: a.seed,
            };
            let options = symmetry.options(None);
            // Planned from a table file, the source is read by the planner (and again by the
            // check).
            let held = if reopenable {
                if let Ok(mut o) = opened.lock() {
                    *o = Some(src);
                }
                None
            } else {
                Some(src)
            };
            let input = match held.as_deref() {
                Some(source) => PackInput::Source {
                    source,
                    grid,
                    options,
                },
                None => PackInput::Reopened {
                    open: &open,
                    grid,
                    options,
                },
            };
            let planned = plan(input, &settings, &progress);
            bar.finish();
            let planned = planned?;
            // The planner's estimation sets, stencils and coefficients are freed: handed back before
            // the read-back and the check, they do not add to the peak.
            crate::memory::release_free_memory();
            let bytes = native::to_bytes_with_payload(
                &planned.table,
                &planned.encoded.spec,
                &planned.encoded.payload,
            )?;
            (
                Packed {
                    codec: planned.encoded.spec.clone(),
                    bytes,
                    tabulate_s: planned.tabulate_s,
                    encode_s: planned.encode_s,
                    budget: Some(BudgetReport {
                        bounds: budget.bounds.clone(),
                        default: default_budget,
                        effort,
                        against: "source",
                        file: planned.encoded.estimate.clone(),
                        grid_alone: planned.encoded.floor.clone(),
                        estimate_samples: planned.estimate_samples,
                        confidence_z: CONFIDENCE_Z,
                        samples: a.samples,
                        seed: a.seed,
                        grids: planned.attempts,
                    }),
                    timings: planned.timings,
                    table: TableFacts::of(&planned.table),
                },
                held,
            )
        }
        None => {
            let grid = match grid {
                Some(g) => g,
                None => default_grid(src.as_ref())?,
            };
            let t0 = Instant::now();
            let table = tabulate(src.as_ref(), &grid, &tab_opts);
            bar.finish();
            let table = table?;
            let tabulate_s = t0.elapsed().as_secs_f64();
            let t1 = Instant::now();
            // Without a budget, --codec is given.
            let codec =
                CodecRequest::parse(a.codec.as_deref().unwrap_or("lossless"))?.resolve(&table)?;
            let bytes = native::to_bytes(&table, &codec)?;
            let encode_s = t1.elapsed().as_secs_f64();
            (
                Packed {
                    table: TableFacts::of(&table),
                    codec,
                    bytes,
                    tabulate_s,
                    encode_s,
                    budget: None,
                    timings: vec![
                        ("tabulate".to_string(), tabulate_s),
                        ("encode".to_string(), encode_s),
                    ],
                },
                Some(src),
            )
        }
    };
    let Packed {
        table,
        codec,
        bytes,
        tabulate_s,
        encode_s,
        budget: budget_report,
        mut timings,
    } = packed;
    let src = match held {
        Some(s) => s,
        None => open()?,
    };
    let grid = table.grid.clone();
    // Check what a reader will get: decode the bytes we are about to write.
    let t2 = Instant::now();
    let back = native::from_bytes(&bytes, &a.output)?;
    let decode_s = t2.elapsed().as_secs_f64();
    timings.push(("read back".to_string(), decode_s));
    let t3 = Instant::now();
    let cells = (back.grid().clone(), back.valid().to_vec());
    let cand = InterpolatedTable {
        table: back,
        interp: Interp::Linear,
    };
    let report = check(
        src.as_ref(),
        &cand,
        a.full_check.then_some((&cells.0, &cells.1)),
        &CheckOptions {
            samples: a.samples,
            seed: a.seed,
            all_sets: true,
        },
    )?;
    timings.push(("check".to_string(), t3.elapsed().as_secs_f64()));
    // The planner measured these very bytes on this very set (same pairs, same
    // interpolation): a file that misses its budget, or a --max-* bound, is never written.
    if let Some(code) = refused(&report, budget.as_ref(), &a)? {
        return Ok(code);
    }
    atomic::write_output(&a.output, &bytes)?;
    a.depfile.write(&[a.output.as_path()], &reads)?;
    let raw = table.samples * 4;
    let scene_report = (!scene.is_empty())
        .then(|| scene.report(&full_channels, &table.channels, &grid, table.valid_cells));
    let r = PackReport {
        output: a.output.display().to_string(),
        source: source_name,
        grid: grid.describe(),
        codec,
        cells: grid.cells(),
        valid_cells: table.valid_cells,
        channels: table.channels.len(),
        bytes: bytes.len(),
        raw_f32_bytes: raw,
        compression_ratio: raw as f64 / bytes.len() as f64,
        bits_per_sample: bytes.len() as f64 * 8.0 / table.samples as f64,
        tabulate_s,
        encode_s,
        decode_s,
        check: report,
        // A file is written only within every bound (`refused`).
        bounds_exceeded: Vec::new(),
        budget: budget_report,
        scene: scene_report,
        timings,
    };
    if a.verbose {
        for (stage, secs) in &r.timings {
            eprintln!("brdfpack: {secs:>8.3} s  {stage}");
        }
    }
    // Quiet by default: the human report with -v (stderr), the JSON one with --json
    // (stdout, unless stdout holds the file).
    if a.verbose {
        eprint!("{}", human(&r));
    }
    if a.json {
        print_json(&r, &a)?;
    }
    Ok(0)
}

/// The JSON report on stdout, or on stderr when stdout holds the file (`-o -`).
pub(crate) fn print_json<T: Serialize>(r: &T, a: &PackArgs) -> anyhow::Result<()> {
    let json = format!("{}\n", serde_json::to_string(r)?);
    if a.output.as_os_str() == "-" {
        eprint!("{json}");
    } else {
        out!("{json}");
    }
    Ok(())
}

fn human(r: &PackReport) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let u = &r.check.uniform;
    let _ = writeln!(s, "output        {}", r.output);
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
        let values = |m: &crate::check::Metrics| budget_values(&b.bounds, m);
        write_budget(
            &mut s,
            &BudgetLines {
                bounds: &b.bounds,
                default: b.default,
                file: &b.file,
                samples: b.samples,
                confidence_z: b.confidence_z,
                estimate_samples: b.estimate_samples,
                file_is: "grid + compression",
                alone: (
                    "grid alone",
                    b.grid_alone.check.as_ref().unwrap_or(&b.grid_alone.metrics),
                    "the uncompressed table against the source: what the grid and its \
                     interpolation cost before compression",
                ),
            },
        );
        if b.grids.len() > 1 {
            for g in &b.grids {
                let _ = writeln!(
                    s,
                    "  {} grid {} ({} cells): grid alone {}; {}",
                    if g.chosen { "*" } else { " " },
                    g.grid,
                    g.cells,
                    values(&g.floor.upper),
                    g.payload_bytes
                        .map_or("misses the budget by itself".to_string(), |n| format!(
                            "{n} bytes of payload"
                        ))
                );
            }
        }
    }
    let _ = writeln!(
        s,
        "check         uniform set, {} pairs, seed {}, linear interpolation; ε = {:.3e}",
        u.samples,
        u.seed.unwrap_or(0),
        u.combined.epsilon
    );
    write_check_metrics(&mut s, &u.combined, r.check.worst_other.as_ref());
    if let Some(sc) = &r.scene {
        let _ = writeln!(
            s,
            "scene         {}; channels {} of {}; {} of {} cells outside the domain (not stored); {:.1}% of the full table's values kept",
            sc.domain,
            sc.channels_kept.join("/"),
            sc.channels_in.join("/"),
            sc.cells_dropped,
            sc.cells,
            100.0 * sc.values_kept_fraction
        );
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

/// Whether the written file's check refuses it: an error when the budget is missed (the
/// planner measured these very bytes on this set, so that would be a bug), `Some(1)` after
/// saying so when a `--max-*` bound is exceeded (a failed bound never replaces a good file),
/// `None` when it may be written.
pub(crate) fn refused(
    report: &crate::check::CheckReport,
    budget: Option<&Budget>,
    a: &PackArgs,
) -> anyhow::Result<Option<i32>> {
    if let Some(b) = budget
        && !b.met_by(&report.uniform.combined)
    {
        return Err(crate::Error::Failure(format!(
            "--max-error: the packed file misses the budget against the source on the check \
             ({}); no file written",
            b.exceeded(&report.uniform.combined).join(", ")
        ))
        .into());
    }
    let failed = verdict(report, &a.bounds);
    if !failed.is_empty() {
        eprintln!(
            "brdfpack: bounds exceeded: {}; {} not written",
            failed.join("; "),
            a.output.display()
        );
        return Ok(Some(1));
    }
    Ok(None)
}

/// The check's metric lines of a pack report: each metric on the uniform set, and the worst
/// of the other sets beside it when they were run.
pub(crate) fn write_check_metrics(
    s: &mut String,
    uniform: &crate::check::Metrics,
    worst: Option<&crate::check::Metrics>,
) {
    use std::fmt::Write as _;
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
        let v = fmt_num(uniform.get(name));
        let _ = match worst.and_then(|w| w.get(name)) {
            Some(w) => writeln!(
                s,
                "{name:<13} {v:<11}  (worst of grazing/specular/cells: {})",
                fmt_num(Some(w))
            ),
            None => writeln!(s, "{name:<13} {v}"),
        };
    }
}

/// The bounded metrics' values of `m`, `name value, …` in the budget's order.
pub(crate) fn budget_values(bounds: &[(String, f64)], m: &crate::check::Metrics) -> String {
    bounds
        .iter()
        .map(|(k, _)| format!("{k} {}", fmt_num(m.get(k))))
        .collect::<Vec<_>>()
        .join(", ")
}

/// What a pack report's budget lines say: the bounds, the written file's error (on the check
/// set and as upper values), and what the representation alone costs.
pub(crate) struct BudgetLines<'a> {
    pub bounds: &'a [(String, f64)],
    pub default: bool,
    pub file: &'a Estimate,
    pub samples: usize,
    pub confidence_z: f64,
    pub estimate_samples: usize,
    /// What the file's error is made of, in words (`grid + compression`).
    pub file_is: &'a str,
    /// (label, metrics, what they are) of the representation before coding.
    pub alone: (&'a str, &'a crate::check::Metrics, &'a str),
}

/// The budget lines of a pack report (`pack` on a grid and an RGL file in its own form).
pub(crate) fn write_budget(s: &mut String, b: &BudgetLines) {
    use std::fmt::Write as _;
    let bounds: Vec<String> = b.bounds.iter().map(|(k, v)| format!("{k} ≤ {v}")).collect();
    let _ = writeln!(
        s,
        "budget        {}{}: met by the written file against the source",
        bounds.join(", "),
        if b.default {
            " (default; --max-error or --codec to change)"
        } else {
            ""
        },
    );
    if let Some(c) = &b.file.check {
        let _ = writeln!(
            s,
            "  file        {} on the check set below (the file against the source: {})",
            budget_values(b.bounds, c),
            b.file_is
        );
    }
    let _ = writeln!(
        s,
        "              {} at most on any independent uniform set of {} pairs ({}σ upper values from {} stratified pairs)",
        budget_values(b.bounds, &b.file.upper),
        b.samples,
        b.confidence_z,
        b.estimate_samples
    );
    let (label, alone, what) = b.alone;
    let _ = writeln!(
        s,
        "  {label:<11} {} ({what})",
        budget_values(b.bounds, alone)
    );
}
